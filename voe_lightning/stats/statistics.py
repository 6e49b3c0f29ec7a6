"""Violation-of-expectation statistics (docs/architecture.md §8): the one-tailed paired t-test
of S(inconsistent) - S(consistent), as infant looking-time studies use it, in the one-shot form
reports use (``paired_test``, ``pooled_test``), on the t-tests from moments of
``voe_lightning.stats.t_tests``, which the streaming torchmetrics form of the training-time
callbacks (``voe_lightning.stats.streaming_statistics``) shares, so both decide degenerate cases
the same way. Which rows a table has and the verdict they give are in
``voe_lightning.stats.verdicts``; how a row is written, in ``voe_lightning.stats.statistics_format``.

A NaN or infinite surprise is a ``ValueError`` naming how many pairs are affected
(``as_float64``); fewer than two pairs and zero variance are decided in
``voe_lightning.stats.t_tests``.

A concept with a counterbalanced pair is also tested ``pooled`` (docs/architecture.md §8): a
stratified test of the mean of its variants' mean differences,
M = (M_standard + M_counterbalanced) / 2, with SE = 0.5 * sqrt(s1^2/n1 + s2^2/n2) and
Welch-Satterthwaite df (``stratified_test``, and ``pooled_test`` for per-pair input). The
variants' cue differences point opposite ways by design, so a test over the union of their pairs
would count that split as noise.

A concept whose variants are the halves of quadruplets, one per seed (``specs.QUADRUPLETS``,
docs/architecture.md §4), is also tested over each of them (``quadruplet_test``): per quadruplet
D = [S(AB) - S(A)] + [S(BA) - S(B)], the one-tailed t-test of D's mean, with the two halves' mean
differences beside it. Its inconsistent videos hold exactly the consistent ones' frames after
the change, so any scorer of those frames alone has D = 0 in every quadruplet.

Every test takes its significance level, ``alpha``, from the caller: a run's one alpha lives in
its config (``alpha:``, configs/base.yaml), which the CLI hands to every callback and command.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
from scipy import optimize, stats
from torchmetrics.functional.classification import binary_auroc

from voe_lightning.specs import QUADRUPLET_ROWS
from voe_lightning.stats.t_tests import (
    rounding_as_zero,
    rounding_of,
    stratified_test,
    t_test_from_moments,
)

__all__ = [
    "POOLED",
    "POOLED_VARIANTS",
    "PairedTestResult",
    "QuadrupletTestResult",
    "as_float64",
    "check_alpha",
    "effect_size_interval",
    "group_test",
    "paired_test",
    "pooled_test",
    "quadruplet_test",
    "ranked_auroc",
    "relative_surprise",
    "untested_reason",
]

#: The row name of a concept's pooled test, and the variants it pools
#: (docs/architecture.md §4, §8).
POOLED = "pooled"
POOLED_VARIANTS: tuple[str, str] = ("standard", "counterbalanced")


def check_alpha(alpha: Any) -> float:
    """``alpha`` as a float if it is a significance level in (0, 1); a ValueError otherwise."""
    if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be a significance level in (0, 1), e.g. 0.01; got {alpha!r}")
    return float(alpha)


def as_float64(values: Any, name: str) -> np.ndarray:
    """Per-pair values (tensor, array or sequence) as a finite float64 vector; a clear
    ``ValueError`` for the wrong shape or for NaN/infinite entries, naming how many."""
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu().double().numpy()
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 1:
        raise ValueError(
            f"{name} must be one surprise per pair, shape [n]; got shape {tuple(array.shape)} "
            "(sum per-frame surprise over frames first)"
        )
    bad = ~np.isfinite(array)
    if bad.any():
        n_nan = int(np.isnan(array).sum())
        raise ValueError(
            f"{name} has {int(bad.sum())} non-finite value(s) out of {array.size} "
            f"({n_nan} NaN, {int(bad.sum()) - n_nan} infinite), first at index "
            f"{int(np.flatnonzero(bad)[0])}; the model produced invalid surprise"
        )
    return array


def relative_surprise(
    inconsistent: Any, consistent: Any, rounding: float | None = None
) -> np.ndarray:
    """Per-pair relative surprise d = S(inconsistent) - S(consistent), float64 [n], each d
    within ``rounding`` of its pair's surprise 0 (``t_tests.rounding_as_zero``)."""
    inc = as_float64(inconsistent, "inconsistent surprise")
    con = as_float64(consistent, "consistent surprise")
    if inc.shape != con.shape:
        raise ValueError(
            f"inconsistent and consistent surprise must pair up one to one; got {inc.size} "
            f"inconsistent and {con.size} consistent values"
        )
    d: np.ndarray = rounding_as_zero(inc, con, rounding)
    return d


def effect_size_interval(t: float, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Confidence interval of d_z = M / s from the noncentral t distribution: t * sqrt(n) ~
    nct(df=n-1, nc=delta * sqrt(n)); the bounds are the nc at which the observed t is the
    upper/lower (1-confidence)/2 quantile, divided by sqrt(n). Falls back to the normal
    approximation SE = sqrt(1/n + d_z^2 / (2n)) if the root cannot be bracketed."""
    if not math.isfinite(t):
        return (t, t)
    df, root_n = n - 1, math.sqrt(n)
    tail = (1.0 - confidence) / 2.0

    def solve(target: float, direction: float) -> float:
        def gap(nc: float) -> float:
            return float(stats.nct.cdf(t, df, nc)) - target

        step = 1.0 + abs(t)
        near, far = t, t + direction * step
        for _ in range(60):
            if gap(near) * gap(far) <= 0:
                root: float = optimize.brentq(gap, min(near, far), max(near, far), xtol=1e-12)
                return root / root_n
            near, far, step = far, far + direction * step, step * 2.0
        raise RuntimeError("could not bracket the noncentrality parameter")

    try:
        return (solve(1.0 - tail, -1.0), solve(tail, +1.0))
    except (RuntimeError, ValueError):
        d_z = t / root_n
        half = stats.norm.ppf(1.0 - tail) * math.sqrt(1.0 / n + d_z * d_z / (2.0 * n))
        return (d_z - half, d_z + half)


@dataclass(frozen=True)
class PairedTestResult:
    """Everything the paper reports for one concept/variant, with d = S(inc) - S(con).

    ``relative_surprise`` is the paper's M (mean of d; a pooled row's: the mean of its
    variants' means, ``pooled_test``, whose ``df`` is a real number); ``p_value`` is
    one-tailed (H1: M > 0);
    ``d_z`` = M / sd with a noncentral-t interval; ``accuracy`` is the share of pairs with
    d > 0 (the relative accuracy); ``auroc`` is the area under the ROC curve for telling
    inconsistent from consistent videos by surprise alone (unpaired); the
    ``relative_surprise_ci_*`` bounds are a bootstrap (BCa) interval of M. ``note`` explains
    any degenerate case (``voe_lightning.stats.t_tests``); it is empty otherwise."""

    n: int
    relative_surprise: float
    sd: float
    t: float
    df: float
    p_value: float
    significant: bool
    alpha: float
    d_z: float
    d_z_ci_low: float
    d_z_ci_high: float
    accuracy: float
    auroc: float
    relative_surprise_ci_low: float
    relative_surprise_ci_high: float
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        """Plain Python values, in field order (for JSON/CSV rows)."""
        return asdict(self)


def ranked_auroc(positive: np.ndarray, negative: np.ndarray) -> float:
    """torchmetrics' binary AUROC of scores (e.g. surprise, inconsistent = positive), ties
    counting half. Scores are fed as ranks scaled into (0, 1]: torchmetrics treats scores
    outside [0, 1] as logits and squashes them with a sigmoid, which would tie large ones;
    ranks keep the order."""
    scores = np.concatenate([positive, negative])
    ranks = stats.rankdata(scores) / scores.size
    target = torch.cat([torch.ones(positive.size), torch.zeros(negative.size)]).long()
    return float(binary_auroc(torch.from_numpy(ranks), target))


def _bootstrap_mean_interval(
    parts: Sequence[np.ndarray], resamples: int, seed: int
) -> tuple[float, float]:
    """BCa 95% interval of the mean of the parts' means, each part resampled on its own (one
    part: the mean of d; a pooled row's variants: the stratified mean)."""

    def mean_of_means(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
        means: np.ndarray = np.mean([np.mean(sample, axis=axis) for sample in samples], axis=0)
        return means

    size = sum(part.size for part in parts)
    result = stats.bootstrap(
        tuple(parts),
        mean_of_means,
        n_resamples=resamples,
        confidence_level=0.95,
        method="BCa",
        rng=np.random.default_rng(seed),
        batch=max(1, min(resamples, 2_000_000 // size)),
    )
    low, high = result.confidence_interval
    if not (np.isfinite(low) and np.isfinite(high)):  # BCa undefined (e.g. n=2): percentile
        low, high = np.percentile(result.bootstrap_distribution, [2.5, 97.5])
    return (float(low), float(high))


def _check_options(alpha: float, bootstrap: int) -> None:
    check_alpha(alpha)
    if bootstrap < 0:
        raise ValueError(f"bootstrap must be a number of resamples >= 0, got {bootstrap}")


def _result(
    inc: np.ndarray,
    con: np.ndarray,
    d: np.ndarray,
    parts: Sequence[np.ndarray],
    mean: float,
    t: float,
    df: float,
    p_value: float,
    note: str,
    d_z_interval: tuple[float, float],
    alpha: float,
    bootstrap: int,
    seed: int,
) -> PairedTestResult:
    """The report row of a test of d (inc - con, rounding as 0), whatever test gave M, t, df
    and p: d_z is M over the SD of every pair's d, accuracy and AUROC count every pair;
    ``parts`` are what the bootstrap of M resamples separately."""
    sd = float(np.std(d, ddof=1))
    zero_error = not math.isfinite(t) or sd == 0.0
    d_z = t if zero_error else mean / sd  # +inf, -inf, or nan when every d = 0
    notes = [note] if note else []
    if zero_error:  # every resample has the same mean
        mean_low = mean_high = mean
    elif bootstrap:
        mean_low, mean_high = _bootstrap_mean_interval(parts, bootstrap, seed)
    else:
        mean_low = mean_high = math.nan
        notes.append("bootstrap interval of M not computed (bootstrap=0)")
    return PairedTestResult(
        n=d.size,
        relative_surprise=mean,
        sd=0.0 if zero_error else sd,
        t=t,
        df=df,
        p_value=p_value,
        significant=bool(p_value < alpha),
        alpha=alpha,
        d_z=d_z,
        d_z_ci_low=d_z_interval[0],
        d_z_ci_high=d_z_interval[1],
        accuracy=float(np.mean(d > 0)),
        auroc=ranked_auroc(inc, con),
        relative_surprise_ci_low=mean_low,
        relative_surprise_ci_high=mean_high,
        note="; ".join(notes),
    )


def paired_test(
    inconsistent: Any,
    consistent: Any,
    alpha: float,
    bootstrap: int = 2000,
    seed: int = 0,
    rounding: float | None = None,
) -> PairedTestResult:
    """One-tailed paired t-test of per-pair surprise, H1: mean(inconsistent - consistent) > 0.
    Agrees with ``scipy.stats.ttest_rel(inconsistent, consistent, alternative="greater")`` but
    for d within ``rounding`` (None: ``t_tests.rounding_of`` the values), which count as 0.
    ``bootstrap`` resamples (seeded by ``seed``) give the 95% interval of M; 0 skips it and
    reports NaN bounds with a note."""
    _check_options(alpha, bootstrap)
    inc = as_float64(inconsistent, "inconsistent surprise")
    con = as_float64(consistent, "consistent surprise")
    d = relative_surprise(inc, con, rounding)
    if d.size < 2:
        raise ValueError(f"a paired t-test needs at least 2 probe pairs, got n={d.size}")
    test = t_test_from_moments(d.size, float(np.mean(d)), float(np.var(d, ddof=1)))
    return _result(
        inc,
        con,
        d,
        [d],
        test.mean,
        test.t,
        test.df,
        test.p_value,
        test.note,
        effect_size_interval(test.t, d.size),
        alpha,
        bootstrap,
        seed,
    )


def pooled_test(
    inconsistent: Any,
    consistent: Any,
    strata: Sequence[str],
    alpha: float,
    bootstrap: int = 2000,
    seed: int = 0,
    rounding: float | None = None,
) -> PairedTestResult:
    """The pooled row of a concept: ``stratified_test`` over the pairs' ``strata`` (their
    variants, e.g. standard and counterbalanced), so M is the mean of the variants' mean
    differences. ``sd`` and ``d_z`` = M / sd are over every pair's d, accuracy and AUROC count
    every pair; d_z's interval is M's t interval (M +- t_.975(df) SE) over sd, and the
    bootstrap interval of M resamples each variant on its own; d within ``rounding`` is 0, as
    in ``paired_test``."""
    _check_options(alpha, bootstrap)
    inc = as_float64(inconsistent, "inconsistent surprise")
    con = as_float64(consistent, "consistent surprise")
    d = relative_surprise(inc, con, rounding)
    variants = np.asarray(strata, dtype=object)
    if variants.shape != d.shape:
        raise ValueError(
            f"strata must name one variant per pair ({d.size}); got shape {variants.shape}"
        )
    names = list(dict.fromkeys(variants.tolist()))
    reason = untested_reason(POOLED, variants.tolist())
    if reason or len(names) < 2:
        raise ValueError(reason or f"a pooled test needs pairs of at least 2 variants, got {names}")
    parts = [d[variants == name] for name in names]
    test = stratified_test(
        [(part.size, float(np.mean(part)), float(np.var(part, ddof=1))) for part in parts]
    )
    sd = float(np.std(d, ddof=1))
    if test.standard_error > 0.0 and sd > 0.0:
        half = float(stats.t.ppf(0.975, test.df)) * test.standard_error
        d_z_interval = ((test.mean - half) / sd, (test.mean + half) / sd)
    else:
        d_z_interval = (test.t, test.t)
    return _result(
        inc,
        con,
        d,
        parts,
        test.mean,
        test.t,
        test.df,
        test.p_value,
        test.note,
        d_z_interval,
        alpha,
        bootstrap,
        seed,
    )


@dataclass(frozen=True)
class QuadrupletTestResult(PairedTestResult):
    """The quadruplet row: a ``PairedTestResult`` of D = [S(AB) + S(BA)] - [S(A) + S(B)] per
    quadruplet (``n`` quadruplets, ``accuracy`` the share with D > 0, IntPhys' relative
    accuracy), with the mean of each half, ``first_half`` = mean[S(AB) - S(A)] and
    ``second_half`` = mean[S(BA) - S(B)]: a verdict needs both above 0."""

    first_half: float = math.nan
    second_half: float = math.nan


def quadruplet_test(
    first_inconsistent: Any,
    first_consistent: Any,
    second_inconsistent: Any,
    second_consistent: Any,
    alpha: float,
    bootstrap: int = 2000,
    seed: int = 0,
    rounding: float | None = None,
) -> QuadrupletTestResult:
    """One-tailed t-test over quadruplets of D = [S(AB) - S(A)] + [S(BA) - S(B)], H1: mean D > 0,
    from the surprise of each quadruplet's first pair (AB, A) and second pair (BA, B), aligned
    by quadruplet. Agrees with ``scipy.stats.ttest_1samp(D, 0, alternative="greater")``;
    ``bootstrap``, ``seed`` and ``rounding`` (None: of all four) as in ``paired_test``."""
    sides = (first_inconsistent, first_consistent, second_inconsistent, second_consistent)
    if rounding is None:  # of the videos' own values: their sums are float64 ones
        rounding = rounding_of(*sides)
    halves = [
        relative_surprise(first_inconsistent, first_consistent, rounding),
        relative_surprise(second_inconsistent, second_consistent, rounding),
    ]
    if halves[0].shape != halves[1].shape:
        raise ValueError(
            f"the two halves must hold one pair per quadruplet alike; got "
            f"{halves[0].size} first and {halves[1].size} second pairs"
        )
    inconsistent = as_float64(first_inconsistent, "first inconsistent surprise") + as_float64(
        second_inconsistent, "second inconsistent surprise"
    )
    consistent = as_float64(first_consistent, "first consistent surprise") + as_float64(
        second_consistent, "second consistent surprise"
    )
    result = paired_test(inconsistent, consistent, alpha, bootstrap, seed, rounding)
    return QuadrupletTestResult(
        **result.as_dict(),
        first_half=float(np.mean(halves[0])),
        second_half=float(np.mean(halves[1])),
    )


def untested_reason(variant: str, variants: Sequence[str]) -> str:
    """Why a group of ``verdicts.pair_groups`` whose pairs have these ``variants`` gets no
    test, or '' if it gets one: fewer than two pairs; for the pooled row, a variant with fewer
    than two; for a quadruplet row, fewer than two quadruplets (its pairs are halves)."""
    counts = dict.fromkeys(variants, 0)
    for name in variants:
        counts[name] += 1
    if variant in QUADRUPLET_ROWS:
        matched = len(variants) // 2
        return "" if matched >= 2 else (f"only {matched} quadruplet: no test (needs at least 2)")
    if len(variants) < 2:
        return f"only {len(variants)} pair: no test (needs at least 2)"
    short = [f"{name} has {count}" for name, count in counts.items() if count < 2]
    if variant == POOLED and short:
        return f"no pooled test: {', '.join(short)} pair (each variant needs at least 2)"
    return ""


def group_test(
    variant: str,
    inconsistent: Any,
    consistent: Any,
    variants: Sequence[str],
    alpha: float,
    bootstrap: int = 2000,
    seed: int = 0,
    rounding: float | None = None,
) -> PairedTestResult:
    """The test of one row of ``verdicts.pair_groups``: ``pooled_test`` over the pairs' ``variants``
    for the ``POOLED`` row, ``quadruplet_test`` for a quadruplet row (``QUADRUPLET_ROWS``; its
    pairs: the first halves, then the second halves, aligned), ``paired_test`` for any other;
    ``rounding`` as in ``paired_test``."""
    if variant in QUADRUPLET_ROWS:
        half = len(variants) // 2
        inc, con = np.asarray(inconsistent), np.asarray(consistent)
        return quadruplet_test(
            inc[:half], con[:half], inc[half:], con[half:], alpha, bootstrap, seed, rounding
        )
    if variant == POOLED:
        return pooled_test(inconsistent, consistent, variants, alpha, bootstrap, seed, rounding)
    return paired_test(inconsistent, consistent, alpha, bootstrap, seed, rounding)
