"""What the causality check (docs/architecture.md §7) finds, and how it compares a batch of pairs:
a probe pair's two videos are byte-identical before their first difference (the first frame at
which their frames, masks or object states differ; after ``manipulation_frame``), so a causal model's
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
    there and the ``first_frame`` at which any does (None: none does); ``unchecked`` of the
    pairs had no frame to compare (their videos differ from the first frame)."""

    pairs: int = 0
    non_causal: int = 0
    largest_difference: float = 0.0
    first_frame: int | None = None
    unchecked: int = 0

    @property
    def causal(self) -> bool:
        """No pair differs where its videos are identical (also when nothing was compared)."""
        return self.non_causal == 0

    @property
    def checked(self) -> bool:
        """Whether any frame was compared: a check of nothing is no pass."""
        return self.pairs > self.unchecked

    def merge(self, other: Causality) -> Causality:
        """The finding over both sets of pairs."""
        frames = [f for f in (self.first_frame, other.first_frame) if f is not None]
        return Causality(
            self.pairs + other.pairs,
            self.non_causal + other.non_causal,
            max(self.largest_difference, other.largest_difference),
            min(frames) if frames else None,
            self.unchecked + other.unchecked,
        )

    def line(self) -> str:
        """One line for reports, tables and errors."""
        if not self.checked:
            return f"causality: not checked: {self._nothing_compared('pairs')}"
        if self.causal:
            return (
                f"causality: per-frame surprise identical before each pair's first difference "
                f"(where the two videos' inputs are) in all {self.pairs - self.unchecked} pairs"
                f"{self._unchecked_note('pairs')}"
            )
        return (
            f"causality: the model is not causal: per-frame surprise differs where the two "
            f"videos' inputs are identical (before their first difference) in {self.non_causal} of "
            f"{self.pairs} pairs, by up to {self.largest_difference:.6g}, first at frame "
            f"{self.first_frame}; no verdict: {NOT_CAUSAL}"
        )

    def _nothing_compared(self, unit: str) -> str:
        if not self.pairs:
            return f"no {unit} to compare"
        return (
            f"no frame compared: the two videos of each of the {self.pairs} {unit} differ "
            "from their first frame"
        )

    def _unchecked_note(self, unit: str) -> str:
        if not self.unchecked:
            return ""
        return f" compared ({self.unchecked} {unit} differ from their first frame: not compared)"

    def counted(self, unit: str) -> str:
        """The finding in a few words, counting ``unit`` (pairs, cuts)."""
        if not self.checked:
            return f"NOT checked ({self._nothing_compared(unit)})"
        if self.causal:
            return (
                f"causal (surprise identical in all {self.pairs - self.unchecked} {unit}"
                f"{self._unchecked_note(unit)})"
            )
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
            "unchecked_pairs": self.unchecked,
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
    """Compare a batch of pairs' per-frame surprise [N, T] on every frame both videos share:
    before each pair's ``first_difference`` where given (the first frame at which any of its
    inputs differ: they can stay identical for frames after ``manipulation_frame``, and a
    benchmark's pair may differ earlier), else
    through its ``manipulation_frame`` (inclusive)."""
    consistent, inconsistent = _numpy(surprise_consistent), _numpy(surprise_inconsistent)
    steps = consistent.shape[1]
    if first_difference is None:
        shared = _numpy(manipulation_frame).astype(np.int64) + 1
    else:
        shared = _numpy(first_difference).astype(np.int64)
    in_prefix = np.arange(steps)[None, :] < shared[:, None]  # [N, T]
    unchecked = int((~in_prefix.any(axis=1)).sum())
    difference = np.abs(consistent - inconsistent)
    noise = np.maximum(
        ABSOLUTE_NOISE, RELATIVE_NOISE * np.maximum(np.abs(consistent), np.abs(inconsistent))
    )
    differs = in_prefix & ~(difference <= noise)  # NaN on one side only differs too
    differs &= ~(np.isnan(consistent) & np.isnan(inconsistent))
    if not differs.any():
        return Causality(pairs=len(consistent), unchecked=unchecked)
    frames = np.flatnonzero(differs.any(axis=0))
    return Causality(
        pairs=len(consistent),
        non_causal=int(differs.any(axis=1).sum()),
        largest_difference=float(np.nanmax(np.where(differs, difference, 0.0))),
        first_frame=int(frames[0]),
        unchecked=unchecked,
    )
