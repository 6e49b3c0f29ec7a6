"""The RGB-D rung of the learner's perception: what a depth camera and a tracker give, with no 3D
box. Per frame and visible mask id, the mask rung's measures of its pixels (``masks.py``: the
image-plane centroid and half-extents, the area, the mean colour), the mean depth of the same
pixels along the view axis (the first of the record's ``depth`` measures, ``specs.depth_spec``)
and the largest size the id has shown so far (``largest_shown``). Each is a function of frames
<= t and their depth images and masks; no shape label, no amodal state.

Kept by measurement (docs/study/learned_physics.md): the mean depth, with which the rung passed
2, 4 and 2 of 5 at three seeds (offset 17,000,000, version 14), containment and object
persistence at two, which the mask rung without it fails; the largest size shown, with which it
passes 3, 3 and 3 (offset 18,000,000; 3, 4 and 2 at 19,000,000 since given the inertial
baseline), solidity at two seeds, which it failed at every seed without: before the change the
camera shows the tall block's height, at the change no more than the short one's
(``experiments/solidity_heights.py``). The record's other two depth measures (least depth, the
share of the outline a nearer surface cuts) are not read: on 100 validation quadruplets of
version 13 seed 0 passed 2 of 5 with both, 3 without the span, 2 without the cut share
(``experiments/depth_ablation.py``), so neither was kept."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import torch

from voe_lightning import specs
from voe_lightning.model.object_state.masks import MASKS, observe_measured, per_id
from voe_lightning.model.object_state.state import Observations, StateLayout, by_slot

#: An RGB-D-perceived state [cx, cy, mean depth, hx, hy, area, lx, ly, r, g, b]: what moves is
#: the centroid (the mask rung's image plane) and the mean depth (m), so the velocity holds the
#: change in depth; how big it is, the pixels' half-extents, their area and the largest size
#: shown so far (``largest_shown``); its mean colour.
RGBD = StateLayout(
    11, position=slice(0, 3), extent=slice(3, 8), color=slice(8, 11), orientation=None
)


def largest_shown(half: torch.Tensor, mean: torch.Tensor, seen: torch.Tensor) -> torch.Tensor:
    """Each id's largest size shown so far [B, T, N, 2]: its pixels' half-extents ``half``
    [B, T, N, 2] times their ``mean`` depth [B, T, N, 1] (a size at the object, not on the
    image), the most of each over the frames <= t that saw it (``seen`` [B, T, N]); zero where
    the id is not seen at t. A block that sinks behind a screen keeps the height it showed."""
    shown = torch.where(seen[..., None], half * mean, 0.0)
    return torch.where(seen[..., None], shown.cummax(dim=1).values, 0.0)


def mean_depth(depth: torch.Tensor) -> torch.Tensor:
    """What the rung reads of a record's per-id depth measures [..., 3] (``specs.depth_spec``):
    the mean depth alone [..., 1], float32; the least depth and the cut share stay unread."""
    mean = specs.DEPTH_MEASURES.index("mean")
    return depth[..., mean : mean + 1].float()


#: The missing depth, in one line: what reads it and which records carry it.
NO_DEPTH = (
    "the object-state model with perception: rgbd reads each video's per-id depth measures "
    "(specs.depth_spec), but a batch came without {where}; records of stimuli version 13 or "
    "later (GENERATOR_VERSION 13) carry it"
)


def observe_rgbd(
    mask: torch.Tensor, frames: torch.Tensor, depth: torch.Tensor | None, camera: torch.Tensor
) -> Observations:
    """What the RGB-D rung reads of a batch of videos: per slot (a mask id, ordered as
    ``state.observe`` orders them) and frame, the ``RGBD`` state of its visible pixels, from
    ``mask`` [B, T, H, W], ``frames`` [B, T, H, W, 3] and ``depth`` [B, T, K, 3]; its area as
    the visible share, no shape and the camera poses. Frame t's observations read frame t
    alone. Without a ``depth`` (a batch that lacks it), a ValueError in one line."""
    if depth is None:
        raise ValueError(NO_DEPTH.format(where="batch key 'depth'"))
    return observe_rgbd_measured(per_id(mask, frames, depth), camera)


def observe_rgbd_measured(
    measured: Mapping[str, torch.Tensor], camera: torch.Tensor
) -> Observations:
    """``observe_rgbd`` from a batch's ``per_id`` measures made with its depth (held per clip,
    ``train_fields: [mask_features, camera]``, or made now): the mask rung's observations
    (``masks.observe_measured``) with each slot's depth measures laid into its state."""
    if "depth" not in measured:
        raise ValueError(NO_DEPTH.format(where="'depth' among its mask_features"))
    seen = observe_measured({k: v for k, v in measured.items() if k != "depth"}, camera)
    # zero where the id is not seen (``per_id``), as every other measure is
    mean = by_slot(mean_depth(measured["depth"]), seen.ids)
    masks = seen.state
    largest = largest_shown(masks[..., MASKS.extent][..., :2], mean, seen.visible)
    state = torch.cat(
        [
            masks[..., MASKS.position],
            mean,
            masks[..., MASKS.extent],
            largest,
            masks[..., MASKS.color],
        ],
        dim=-1,
    )
    return replace(seen, state=state)
