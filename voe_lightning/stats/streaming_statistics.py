"""The streaming form of the paired t-test, for training-time callbacks
(docs/architecture.md §8): ``PairedSurpriseStats`` keeps n, sum d and sum d^2 as float64
torchmetrics states, so a DDP reduction gives exactly the one-pass result; ``pooled_values``
pools a concept's variants into its stratified row. The tests are those of
``voe_lightning.stats.t_tests``, as the one-shot ones of ``voe_lightning.stats.statistics`` are,
so the streaming and one-shot forms decide degenerate cases alike."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torchmetrics import Metric

from voe_lightning.stats.t_tests import rounding_as_zero, stratified_test, t_test_from_moments

__all__ = ["PairedSurpriseStats", "TooFewPairs", "pooled_values"]


class TooFewPairs(ValueError):
    """``PairedSurpriseStats.compute`` of fewer than 2 pairs: no test yet (callbacks wait)."""


class PairedSurpriseStats(Metric):
    """Streaming paired t-test for training-time callbacks: keeps n, sum d, sum d^2 and the
    count of d > 0 as float64 sum-states, so a DDP reduction (or ``merge_state``) gives the
    same result as one pass over all pairs. ``compute()`` returns float64 scalar tensors
    ``relative_surprise`` (mean d), ``t``, ``p_value`` (one-tailed, scipy's t distribution),
    ``accuracy`` (share of d > 0), ``n`` and ``variance`` (of d, ddof=1: what
    ``pooled_values`` pools variants from)."""

    is_differentiable = False
    higher_is_better = None
    full_state_update = False

    n: torch.Tensor
    sum_d: torch.Tensor
    sum_d_squared: torch.Tensor
    positive: torch.Tensor

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        for name in ("n", "sum_d", "sum_d_squared", "positive"):
            self.add_state(name, default=torch.zeros((), dtype=torch.float64), dist_reduce_fx="sum")

    def update(
        self,
        surprise_inconsistent: torch.Tensor,
        surprise_consistent: torch.Tensor,
        rounding: float | None = None,
    ) -> None:
        """Add a batch of pairs: per-video surprise [B] of the inconsistent and consistent video;
        a d within ``rounding`` of its surprise counts as 0 (``t_tests.rounding_as_zero``; None:
        the rounding of these values, where the caller knows no per-frame surprise)."""
        inc = torch.as_tensor(surprise_inconsistent).detach()
        con = torch.as_tensor(surprise_consistent).detach()
        if inc.ndim != 1 or inc.shape != con.shape:
            raise ValueError(
                "update expects per-video surprise of shape [B] for both videos of each pair; "
                f"got inconsistent {tuple(inc.shape)} and consistent {tuple(con.shape)}"
            )
        d = torch.from_numpy(rounding_as_zero(inc.cpu().double(), con.cpu().double(), rounding))
        d = d.to(self.sum_d.device)
        bad = ~torch.isfinite(d)
        if bad.any():
            raise ValueError(
                f"{int(bad.sum())} of {d.numel()} probe pairs in this batch have non-finite "
                f"surprise ({int(torch.isnan(d).sum())} NaN); the model produced invalid surprise"
            )
        self.n += d.numel()
        self.sum_d += d.sum()
        self.sum_d_squared += (d * d).sum()
        self.positive += (d > 0).sum()

    def compute(self) -> dict[str, torch.Tensor]:
        n = int(round(float(self.n)))
        if n < 2:
            raise TooFewPairs(f"PairedSurpriseStats needs at least 2 probe pairs, got n={n}")
        sum_d, sum_squares = float(self.sum_d), float(self.sum_d_squared)
        if not (math.isfinite(sum_d) and math.isfinite(sum_squares)):
            raise ValueError(
                f"moments of the differences are not finite: over n={n} pairs, sum d = "
                f"{sum_d:g}, sum d^2 = {sum_squares:g}; the streaming t-test needs both "
                "within float64 (|d| below about 1e154)"
            )
        mean = sum_d / n
        variance = max(0.0, (sum_squares - n * mean * mean) / (n - 1))
        test = t_test_from_moments(n, mean, variance)
        values = {
            "relative_surprise": test.mean,
            "t": test.t,
            "p_value": test.p_value,
            "accuracy": float(self.positive) / n,
            "n": float(n),
            "variance": variance,
        }
        return {key: torch.tensor(value, dtype=torch.float64) for key, value in values.items()}


def pooled_values(variant_values: Sequence[Mapping[str, float]]) -> dict[str, float]:
    """The pooled row of the streaming form from its variants' ``PairedSurpriseStats`` values
    (n, relative_surprise, variance, accuracy): ``stratified_test``'s M, t, df and p, and the
    share of all their pairs with d > 0."""
    test = stratified_test(
        [
            (int(round(float(v["n"]))), float(v["relative_surprise"]), float(v["variance"]))
            for v in variant_values
        ]
    )
    positive = sum(float(v["accuracy"]) * float(v["n"]) for v in variant_values)
    return {
        "relative_surprise": test.mean,
        "t": test.t,
        "p_value": test.p_value,
        "df": test.df,
        "accuracy": positive / test.n,
        "n": float(test.n),
    }
