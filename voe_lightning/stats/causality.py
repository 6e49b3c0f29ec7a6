"""What the causality check (docs/architecture.md §7) finds, and how it compares a batch of pairs:
a probe pair's two videos are byte-identical through ``manipulation_frame``, so a causal model's
per-frame surprise is identical there. ``check_prefix`` checks one batch of pairs;
``Causality`` is its finding, and ``Causality.merge`` adds batches up. Running a model through
the whole protocol is ``voe_lightning.model.causality``'s (``check_model``, ``check-causality``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

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
