"""The causality check every report and validation run makes (docs/architecture.md §7, DESIGN.md
§5): a probe pair's two videos are byte-identical through ``manipulation_frame``, so a
causal model's per-frame surprise is identical there. Where it differs beyond float noise, the
model reads frames after t (a user's callable scoring frame t from t..t+1, or giving every frame
the video's total), its relative surprise may carry the answer, and no verdict is given.
``check_prefix`` checks one batch of pairs; ``Causality.merge`` adds batches up;
``check_model`` runs a model through the whole protocol (``tests/test_causality.py``'s two
checks), and ``check_causality`` (``python -m voe_lightning check-causality``) does so on
generated probes for a user's model."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.model.base import SurpriseModel, video_inputs

#: Why a verdict is withheld, after ``no verdict: `` (``verdicts.Verdict.text``).
NOT_CAUSAL = "the model reads frames after t"
#: Float noise: surprise within this share of the larger value (or this much absolutely) is
#: identical. bf16 kernels may round identical rows of a batch apart by ~1e-7 relative; a model
#: reading the future differs by far more (37.95 vs 45.63 in issue 51's case).
RELATIVE_NOISE, ABSOLUTE_NOISE = 1e-4, 1e-5


@dataclass(frozen=True)
class Causality:
    """What ``check_prefix`` found over ``pairs`` probe pairs: how many (``non_causal``) have
    per-frame surprise differing where their videos are identical, the ``largest_difference``
    there and the ``first_frame`` at which any does (None: none does)."""

    pairs: int = 0
    non_causal: int = 0
    largest_difference: float = 0.0
    first_frame: int | None = None

    @property
    def causal(self) -> bool:
        return self.non_causal == 0

    def merge(self, other: Causality) -> Causality:
        """The finding over both sets of pairs."""
        frames = [f for f in (self.first_frame, other.first_frame) if f is not None]
        return Causality(
            self.pairs + other.pairs,
            self.non_causal + other.non_causal,
            max(self.largest_difference, other.largest_difference),
            min(frames) if frames else None,
        )

    def line(self) -> str:
        """One line for reports, tables and errors."""
        if self.causal:
            return (
                f"causality: per-frame surprise identical through manipulation_frame "
                f"(where the two videos are) in all {self.pairs} pairs"
            )
        return (
            f"causality: the model is not causal: per-frame surprise differs where the two "
            f"videos are identical (through manipulation_frame) in {self.non_causal} of "
            f"{self.pairs} pairs, by up to {self.largest_difference:.6g}, first at frame "
            f"{self.first_frame}; no verdict: {NOT_CAUSAL}"
        )

    def counted(self, unit: str) -> str:
        """The finding in a few words, counting ``unit`` (pairs, cuts)."""
        if self.causal:
            return f"causal (surprise identical in all {self.pairs} {unit})"
        return (
            f"NOT causal: surprise differs in {self.non_causal} of {self.pairs} {unit}, by "
            f"up to {self.largest_difference:.6g}, first at frame {self.first_frame}"
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            "causal": self.causal,
            "pairs": self.pairs,
            "non_causal_pairs": self.non_causal,
            "largest_difference": self.largest_difference,
            "first_frame": self.first_frame,
        }


def _numpy(values: Any) -> np.ndarray:
    """A tensor or array-like as float64 numpy (on the CPU)."""
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu().double().numpy()
    return np.asarray(values, dtype=np.float64)


def check_prefix(
    surprise_consistent: Any,
    surprise_inconsistent: Any,
    manipulation_frame: Any,
    first_difference: Any = None,
) -> Causality:
    """Compare a batch of pairs' per-frame surprise [N, T] through each pair's
    ``manipulation_frame`` (inclusive), and before its ``first_difference`` where given (a
    benchmark's pair may differ earlier: only frames both videos share are compared)."""
    consistent, inconsistent = _numpy(surprise_consistent), _numpy(surprise_inconsistent)
    steps = consistent.shape[1]
    shared = _numpy(manipulation_frame).astype(np.int64) + 1
    if first_difference is not None:
        shared = np.minimum(shared, _numpy(first_difference).astype(np.int64))
    in_prefix = np.arange(steps)[None, :] < shared[:, None]  # [N, T]
    difference = np.abs(consistent - inconsistent)
    noise = np.maximum(
        ABSOLUTE_NOISE, RELATIVE_NOISE * np.maximum(np.abs(consistent), np.abs(inconsistent))
    )
    differs = in_prefix & ~(difference <= noise)  # NaN on one side only differs too
    differs &= ~(np.isnan(consistent) & np.isnan(inconsistent))
    if not differs.any():
        return Causality(pairs=len(consistent))
    frames = np.flatnonzero(differs.any(axis=0))
    return Causality(
        pairs=len(consistent),
        non_causal=int(differs.any(axis=1).sum()),
        largest_difference=float(np.nanmax(np.where(differs, difference, 0.0))),
        first_frame=int(frames[0]),
    )


def check_model(model: SurpriseModel, probes: Any) -> tuple[Causality, Causality]:
    """The causality protocol of ``model`` (a ``SurpriseModel``) on a batch of probe pairs:
    per-frame surprise identical through each pair's manipulation frame (``check_prefix`` of
    ``probe_step``), and each inconsistent video's surprise up to frame t unchanged when the
    video (frames, masks, camera, object states) is cut after t, for every t (counted once
    per video and frame)."""
    with torch.no_grad():
        scored = model.probe_step(probes)
        prefix = check_prefix(
            scored["surprise_consistent"],
            scored["surprise_inconsistent"],
            scored["manipulation_frame"],
            scored.get("first_difference"),
        )
        frames = probes["inconsistent", "frames"]
        inputs = video_inputs(probes, "inconsistent")
        whole = model.surprise(frames, **inputs)
        cut = Causality()
        for t in range(frames.shape[1] - 1):
            part = model.surprise(
                frames[:, : t + 1], **{name: _through(value, t) for name, value in inputs.items()}
            )
            cut = cut.merge(check_prefix(whole[:, : t + 1], part, torch.full((len(frames),), t)))
    return prefix, cut


def _through(value: Any, t: int) -> Any:
    """A batch of videos' input [B, T, ...] through frame t: a tensor, or object states (a
    TensorDict of batch [B] whose leaves are [B, T, ...])."""
    if isinstance(value, TensorDictBase):
        return value.apply(lambda leaf: leaf[:, : t + 1])
    return value[:, : t + 1]


def check_causality(
    model: SurpriseModel,
    concepts: list[specs.Concept] | None = None,
    seeds: int = 2,
    size: int = 32,
    num_frames: int = 15,
) -> bool:
    """Run a model through the causality protocol on generated probe pairs.

    Surprise at frame t may read frames up to t only: per concept, each pair's per-frame
    surprise must be identical through its manipulation frame (the two videos are), and a
    video cut after t must keep its surprise up to t. Prints one line per check and concept;
    refuses a model that fails (exit status 2). The model is checked as built (causality is
    a property of its computation, not of its weights).

    Args:
        model: the model, e.g. ``--model voe_lightning.model.CallableModel
            --model.init_args.function my_package.surprise``.
        concepts: concepts whose probes to generate (default: all five).
        seeds: probe pairs per concept and variant.
        size: height and width of the generated videos.
        num_frames: frames per video.
    """
    from voe_lightning.scenes import PROBE_VARIANTS, generate_probe  # MuJoCo: only when run

    if seeds < 1:
        raise ValueError(f"seeds must be an integer of at least 1, got {seeds}")
    model.eval()
    failed = []
    for concept in concepts or specs.CONCEPTS:
        probes = torch.stack(
            [
                generate_probe(
                    concept, variant, seed, height=size, width=size, num_frames=num_frames
                )
                for variant in PROBE_VARIANTS[concept]
                for seed in range(seeds)
            ]
        )
        checks = ("pairs through the manipulation frame", "videos cut after each frame t")
        for check, unit, found in zip(checks, ("pairs", "cuts"), check_model(model, probes)):
            print(f"{concept}, {check}: {found.counted(unit)}")
            if not found.causal:
                failed.append(f"{concept} ({check})")
    if failed:
        raise ValueError(
            f"{type(model).__name__} is not causal: its surprise at frame t reads "
            f"later frames in {', '.join(failed)}"
        )
    return True
