"""Finite-loss watch without a host sync per step: the training terms are checked on the device
every step, and the first non-finite step is read back only when asked (every
``log_every_n_steps``, at a checkpoint, at the end), so a NaN is still named with its step."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch


def non_finite_message(step: int, names: Sequence[str], values: Sequence[float]) -> str:
    """The error of a non-finite training loss: the step, the offending terms, all terms."""
    bad = ", ".join(
        f"{name}={value:.4g}" for name, value in zip(names, values) if not math.isfinite(value)
    )
    return (
        f"non-finite loss at global step {step}: {bad} (all terms: "
        f"{dict(zip(names, values))}); stopping before a garbage checkpoint is written. "
        "Try a lower learning_rate or float32 precision."
    )


class FiniteMonitor:
    """Remembers, on the device, the first step whose terms [n] were not all finite, and those
    terms. :meth:`update` launches a few small kernels and never syncs; :meth:`check` syncs
    once and raises ``FloatingPointError`` naming that step and its terms."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)
        self.first_bad_step: torch.Tensor | None = None
        self.bad_terms: torch.Tensor | None = None

    def update(self, terms: torch.Tensor, step: torch.Tensor) -> None:
        """Record ``terms`` [n] of the global ``step`` (a 0-dim int64 tensor on their device)."""
        terms = terms.detach().float()
        if self.first_bad_step is None or self.first_bad_step.device != terms.device:
            self.first_bad_step = torch.full((), -1, dtype=torch.int64, device=terms.device)
            self.bad_terms = torch.zeros_like(terms)
        assert self.bad_terms is not None  # set with first_bad_step
        first = (self.first_bad_step < 0) & ~torch.isfinite(terms).all()
        self.first_bad_step = torch.where(first, step, self.first_bad_step)
        self.bad_terms = torch.where(first, terms, self.bad_terms)

    def check(self) -> None:
        """Raise if any step since the start had a non-finite term (one host sync)."""
        if self.first_bad_step is None:
            return
        step = int(self.first_bad_step)
        if step >= 0:
            assert self.bad_terms is not None  # set with first_bad_step
            raise FloatingPointError(non_finite_message(step, self.names, self.bad_terms.tolist()))
