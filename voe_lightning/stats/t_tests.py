"""The one-tailed t-tests from moments (docs/architecture.md §8): the paired test from n, the
mean and the variance of the differences d (``t_test_from_moments``), and the stratified test
of a concept's variants from each one's (``stratified_test``), shared by the one-shot tests of
``voe_lightning.stats.statistics`` and the streaming ones of
``voe_lightning.stats.streaming_statistics``, so that both decide degenerate cases alike.

Degenerate inputs, decided once here:

- a difference within rounding of its pair's surprise is exactly 0 (``rounding_as_zero``, which
  every test's d comes from): float32 surprise differing by an ulp of 1.43 is no evidence of
  surprise, so rounding alone never makes a test significant (nor t = +inf);
- fewer than two pairs, or moments that are not finite: ``ValueError`` (no variance, no test);
- zero variance of the differences (every pair has the same d): the t statistic is the limit
  of M / (s / sqrt(n)) as s -> 0, so t = +inf, p = 0 when M > 0 and t = -inf, p = 1 when M < 0
  (d_z and its interval are +-inf likewise). When every d is exactly 0 there is no evidence
  for H1 at all: t and d_z are undefined (NaN) and p is set to 1 (not significant). Every such
  result carries a ``note`` saying so, which the report prints beside the row.

The stratified test's M is the mean of the strata's mean differences, with
SE = (1/k) sqrt(sum s_i^2/n_i) and Welch-Satterthwaite df."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from scipy import stats

__all__ = [
    "FLOAT32_ROUNDING",
    "FLOAT64_ROUNDING",
    "StratifiedTest",
    "TTest",
    "rounding_as_zero",
    "rounding_of",
    "stratified_moments",
    "stratified_test",
    "t_and_p",
    "t_test_from_moments",
]

#: Rounding of surprise held in float32 (or narrower), as a share of the larger value of a pair:
#: 16 float32 epsilons, as a sum over frames or a batch's kernels leave a few ulps; and of
#: float64 surprise. Far below the causality check's bf16 noise (1e-4, ``stats.causality``),
#: which would zero real differences such as the cue audit's grey levels (docs/stimuli.md).
FLOAT32_ROUNDING, FLOAT64_ROUNDING = 2.0**-19, 2.0**-48

#: A variance below this fraction of the mean square is treated as exactly zero (the streaming
#: form computes it from sums, where equal differences leave rounding residue of about 1e-16).
_ZERO_VARIANCE_RTOL = 1e-12


@dataclass(frozen=True)
class TTest:
    """One-tailed paired t-test (H1: mean d > 0) from the moments of d."""

    n: int
    mean: float
    sd: float
    t: float
    df: int
    p_value: float
    note: str


def rounding_of(*values: Any) -> float:
    """The rounding of surprise ``values`` (tensors or arrays): ``FLOAT32_ROUNDING`` when every
    value is a float32 one (as the surprise of a float32 model is, even summed or stored in
    float64), ``FLOAT64_ROUNDING`` otherwise (a float64 scorer's, whose small d are real)."""
    for value in values:
        if isinstance(value, torch.Tensor):
            value = value.detach().cpu().double().numpy()
        array = np.asarray(value, dtype=np.float64)
        if not np.array_equal(array, array.astype(np.float32), equal_nan=True):
            return FLOAT64_ROUNDING
    return FLOAT32_ROUNDING


def rounding_as_zero(inconsistent: Any, consistent: Any, rounding: float | None = None) -> Any:
    """d = inconsistent - consistent in float64, each d within ``rounding`` (a share of its
    pair's larger surprise; None: ``rounding_of`` the values) set to exactly 0."""
    inc, con = np.asarray(inconsistent, np.float64), np.asarray(consistent, np.float64)
    share = rounding_of(inc, con) if rounding is None else rounding
    with np.errstate(invalid="ignore"):  # inf - inf: NaN, which callers refuse
        d = inc - con
        within = np.isfinite(d) & (np.abs(d) <= share * np.maximum(np.abs(inc), np.abs(con)))
    return np.where(within, 0.0, d)


def t_and_p(mean: Any, standard_error: Any, df: Any) -> tuple[Any, Any]:
    """t = M / SE and its one-tailed p (H1: M > 0) from scipy's t distribution; numpy arrays
    broadcast (the calibration tests thousands of repetitions at once) as scalars do."""
    t = np.divide(mean, standard_error)
    return t, stats.t.sf(t, df)


def _is_zero_variance(n: int, mean: float, variance: float) -> bool:
    """Whether a variance is zero up to the rounding residue of sums (``_ZERO_VARIANCE_RTOL``)."""
    return variance <= _ZERO_VARIANCE_RTOL * (variance * (n - 1) / n + mean * mean)


def _degenerate(mean: float) -> tuple[float, float, str]:
    """t, p and note of a test whose standard error is zero (module docstring)."""
    if mean > 0:
        return math.inf, 0.0, f"zero variance: every d = {mean:.6g} > 0, so t = +inf, p = 0"
    if mean < 0:
        return -math.inf, 1.0, f"zero variance: every d = {mean:.6g} < 0, so t = -inf, p = 1"
    return (
        math.nan,
        1.0,
        "every d = 0 (up to rounding of the surprise): no difference at all; t and d_z "
        "undefined, p set to 1",
    )


def _check_moments(n: int, mean: float, variance: float) -> None:
    """Refuse moments no t-test can use: fewer than 2 pairs, or a mean or variance not finite."""
    if n < 2:
        raise ValueError(f"a paired t-test needs at least 2 probe pairs, got n={n}")
    if not (math.isfinite(mean) and math.isfinite(variance)):
        raise ValueError(f"moments of the differences are not finite: mean={mean}, var={variance}")


def t_test_from_moments(n: int, mean: float, variance: float) -> TTest:
    """The one-tailed paired t-test from n, the mean and the (ddof=1) variance of d, with the
    degenerate cases of the module docstring. p comes from scipy's t distribution."""
    _check_moments(n, mean, variance)
    df = n - 1
    if _is_zero_variance(n, mean, variance):
        t, p, note = _degenerate(mean)
        return TTest(n, 0.0 if math.isnan(t) else mean, 0.0, t, df, p, note)
    sd = math.sqrt(variance)
    t, p = t_and_p(mean, sd / math.sqrt(n), df)
    return TTest(n, mean, sd, float(t), df, float(p), "")


@dataclass(frozen=True)
class StratifiedTest:
    """The pooled test of a concept's variants (strata): ``mean`` is the unweighted mean of
    their mean differences, ``standard_error`` its SE, ``df`` Welch-Satterthwaite's (a real
    number), ``p_value`` one-tailed (H1: mean > 0); ``n`` counts the pairs of every stratum."""

    n: int
    mean: float
    standard_error: float
    t: float
    df: float
    p_value: float
    note: str


def stratified_moments(n: Any, mean: Any, variance: Any) -> tuple[Any, Any, Any]:
    """The mean of k strata's mean differences, its standard error (1/k) sqrt(sum s_i^2/n_i)
    and the Welch-Satterthwaite df (sum s_i^2/n_i)^2 / sum (s_i^2/n_i)^2/(n_i - 1), from each
    stratum's n, mean and (ddof=1) variance along axis 0 (arrays broadcast over the rest)."""
    n, mean, variance = (np.asarray(x, dtype=np.float64) for x in (n, mean, variance))
    n = n.reshape(n.shape + (1,) * (variance.ndim - n.ndim))  # one n per stratum
    squared_errors = variance / n
    total = squared_errors.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        df = total * total / (squared_errors * squared_errors / (n - 1)).sum(axis=0)
    return mean.mean(axis=0), np.sqrt(total) / n.shape[0], df


def stratified_test(strata: Sequence[tuple[int, float, float]]) -> StratifiedTest:
    """The stratified test from each stratum's (n, mean, variance) of d (module docstring).
    A stratum whose variance is zero up to rounding counts as zero; when every one is, the
    degenerate rule of the module docstring decides (t = +-inf, or NaN with p = 1)."""
    if len(strata) < 2:
        raise ValueError(f"a stratified test needs at least 2 strata (variants), got {len(strata)}")
    for n, mean, variance in strata:
        _check_moments(n, mean, variance)
    variances = [
        0.0 if _is_zero_variance(n, mean, variance) else variance for n, mean, variance in strata
    ]
    ns, means = [n for n, _, _ in strata], [mean for _, mean, _ in strata]
    mean, standard_error, df = (float(x) for x in stratified_moments(ns, means, variances))
    if standard_error == 0.0:
        t, p, note = _degenerate(mean)
        return StratifiedTest(sum(ns), mean, 0.0, t, math.nan, p, note)
    t, p = t_and_p(mean, standard_error, df)
    return StratifiedTest(sum(ns), mean, standard_error, float(t), df, float(p), "")
