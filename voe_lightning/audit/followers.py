"""The physics-blind followers of a model's own inputs as rows of the cue audit (issue 70):
each ``ObjectFollower`` rule over the object states or the masks, scored per video as the
pixel cues are (its surprise summed over the frames after the manipulation frame), so a report
on a model that reads states or masks shows what a rule with no dynamics makes of the same
pairs. A concept one of them passes is a shortcut in the model's inputs (or, for
unchangeableness' attribute memory, the concept itself)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import torch

from voe_lightning.audit.video_cues import frames_after
from voe_lightning.model.scorers.followers import RULES, follower_inputs, rule_surprise

__all__ = ["FEATURES_OF_INPUT", "features_read", "follower_cues", "follower_title", "score"]

#: Which followers a model's ``inputs_read`` calls for: the states' for ``objects``, the
#: masks' for ``mask``, the masks' with depth for ``depth``.
FEATURES_OF_INPUT = {"objects": "states", "mask": "masks", "depth": "rgbd"}


def features_read(inputs_read: Iterable[str]) -> tuple[str, ...]:
    """The follower features (``states``, ``masks``, ``rgbd``) of a model that reads
    ``inputs_read``."""
    read = set(inputs_read)
    return tuple(features for name, features in FEATURES_OF_INPUT.items() if name in read)


def follower_cues(features: str) -> tuple[str, ...]:
    """The audit's cue names of the followers of ``features``: ``<features>_<rule>``."""
    return tuple(f"{features}_{rule}" for rule in RULES)


def follower_title(cue: str) -> str:
    """A column title: 'states: stay put'."""
    features, rule = cue.split("_", 1)
    return f"{features}: {rule.replace('_', ' ')}"


def score(
    video: Mapping[str, Any], manipulation_frame: torch.Tensor, features: Iterable[str]
) -> dict[str, np.ndarray]:
    """Each follower's score of a batch of videos (``frames``, and ``mask``/``objects``/``depth``
    where the batch has them): float64 [B] per cue of ``follower_cues``, its surprise summed
    over the frames t > m; NaN for features the videos lack (masks all zero count as lacking)."""
    frames = video["frames"]
    keys = set(video.keys())
    mask = video["mask"] if "mask" in keys else None
    objects = video["objects"] if "objects" in keys else None
    depth = video["depth"] if "depth" in keys else None
    after = frames_after(manipulation_frame.reshape(-1).long(), frames.shape[1])
    scores: dict[str, np.ndarray] = {}
    for name in features:
        lacking = (objects is None) if name == "states" else (mask is None or not bool(mask.any()))
        if lacking or (name == "rgbd" and depth is None):
            scores.update(dict.fromkeys(follower_cues(name), np.full(len(frames), np.nan)))
            continue
        inputs = follower_inputs(name, frames, mask, objects, depth)
        for rule in RULES:
            total = (rule_surprise(rule, name, inputs).double() * after).sum(dim=1)
            scores[f"{name}_{rule}"] = total.cpu().numpy()
    return scores
