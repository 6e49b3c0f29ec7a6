"""Violation-of-expectation statistics (DESIGN.md §6): the one-tailed paired t-test of
S(inconsistent) - S(consistent), as infant looking-time studies use it, in a one-shot form for
reports (``paired_test``) and a streaming torchmetrics form for training-time callbacks
(``PairedSurpriseStats``). Both share ``t_test_from_moments`` so they decide degenerate cases
the same way.

Degenerate inputs, decided once here:

- fewer than two pairs: ``ValueError`` (no variance, no test);
- a NaN or infinite surprise: ``ValueError`` naming how many pairs are affected;
- zero variance of the differences (every pair has the same d): the t statistic is the limit
  of M / (s / sqrt(n)) as s -> 0, so t = +inf, p = 0 when M > 0 and t = -inf, p = 1 when M < 0
  (d_z and its interval are +-inf likewise). When every d is exactly 0 there is no evidence
  for H1 at all: t and d_z are undefined (NaN) and p is set to 1 (not significant). Every such
  result carries a ``note`` saying so, which the report prints beside the row.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
from scipy import optimize, stats
from torchmetrics import Metric
from torchmetrics.functional.classification import binary_auroc

from voe_lightning import specs

__all__ = [
    "POOLED",
    "POOLED_VARIANTS",
    "PairedSurpriseStats",
    "PairedTestResult",
    "TTest",
    "Verdict",
    "as_float64",
    "concept_verdicts",
    "effect_size_interval",
    "paired_test",
    "pair_groups",
    "relative_surprise",
    "t_test_from_moments",
]

#: The row name of a concept's pooled test, and the variants it pools (DESIGN.md §4, §6).
POOLED = "pooled"
POOLED_VARIANTS: tuple[str, str] = ("standard", "counterbalanced")

#: A variance below this fraction of the mean square is treated as exactly zero (the streaming
#: form computes it from sums, where equal differences leave rounding residue of about 1e-16).
_ZERO_VARIANCE_RTOL = 1e-12


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


def relative_surprise(inconsistent: Any, consistent: Any) -> np.ndarray:
    """Per-pair relative surprise d = S(inconsistent) - S(consistent), float64 [n]."""
    inc = as_float64(inconsistent, "inconsistent surprise")
    con = as_float64(consistent, "consistent surprise")
    if inc.shape != con.shape:
        raise ValueError(
            f"inconsistent and consistent surprise must pair up one to one; got {inc.size} "
            f"inconsistent and {con.size} consistent values"
        )
    return inc - con


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


def t_test_from_moments(n: int, mean: float, variance: float) -> TTest:
    """The one-tailed paired t-test from n, the mean and the (ddof=1) variance of d, with the
    degenerate cases of the module docstring. p comes from scipy's t distribution."""
    if n < 2:
        raise ValueError(f"a paired t-test needs at least 2 probe pairs, got n={n}")
    if not (math.isfinite(mean) and math.isfinite(variance)):
        raise ValueError(f"moments of the differences are not finite: mean={mean}, var={variance}")
    df = n - 1
    mean_square = variance * df / n + mean * mean
    if variance <= _ZERO_VARIANCE_RTOL * mean_square:
        if mean > 0:
            return TTest(n, mean, 0.0, math.inf, df, 0.0,
                         f"zero variance: every d = {mean:.6g} > 0, so t = +inf, p = 0")
        if mean < 0:
            return TTest(n, mean, 0.0, -math.inf, df, 1.0,
                         f"zero variance: every d = {mean:.6g} < 0, so t = -inf, p = 1")
        return TTest(n, 0.0, 0.0, math.nan, df, 1.0,
                     "every d = 0: no difference at all; t and d_z undefined, p set to 1")
    sd = math.sqrt(variance)
    t = mean / (sd / math.sqrt(n))
    return TTest(n, mean, sd, t, df, float(stats.t.sf(t, df)), "")


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
                return optimize.brentq(gap, min(near, far), max(near, far), xtol=1e-12) / root_n
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

    ``relative_surprise`` is the paper's M (mean of d); ``p_value`` is one-tailed (H1: M > 0);
    ``d_z`` = M / sd with a noncentral-t interval; ``accuracy`` is the share of pairs with
    d > 0 (the relative accuracy); ``auroc`` is the area under the ROC curve for telling
    inconsistent from consistent videos by surprise alone (unpaired); the
    ``relative_surprise_ci_*`` bounds are a bootstrap (BCa) interval of M. ``note`` explains
    any degenerate case (module docstring); it is empty otherwise."""

    n: int
    relative_surprise: float
    sd: float
    t: float
    df: int
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


def _bootstrap_mean_interval(d: np.ndarray, resamples: int, seed: int) -> tuple[float, float]:
    result = stats.bootstrap(
        (d,), np.mean, n_resamples=resamples, confidence_level=0.95, method="BCa",
        rng=np.random.default_rng(seed), batch=max(1, min(resamples, 2_000_000 // d.size)),
    )
    low, high = result.confidence_interval
    if not (np.isfinite(low) and np.isfinite(high)):  # BCa undefined (e.g. n=2): percentile
        low, high = np.percentile(result.bootstrap_distribution, [2.5, 97.5])
    return (float(low), float(high))


def paired_test(
    inconsistent: Any,
    consistent: Any,
    alpha: float = 0.05,
    bootstrap: int = 2000,
    seed: int = 0,
) -> PairedTestResult:
    """One-tailed paired t-test of per-pair surprise, H1: mean(inconsistent - consistent) > 0.
    Agrees with ``scipy.stats.ttest_rel(inconsistent, consistent, alternative="greater")``.
    ``bootstrap`` resamples (seeded by ``seed``) give the 95% interval of M; 0 skips it and
    reports NaN bounds with a note."""
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    if bootstrap < 0:
        raise ValueError(f"bootstrap must be a number of resamples >= 0, got {bootstrap}")
    inc = as_float64(inconsistent, "inconsistent surprise")
    con = as_float64(consistent, "consistent surprise")
    d = relative_surprise(inc, con)
    n = d.size
    if n < 2:
        raise ValueError(f"a paired t-test needs at least 2 probe pairs, got n={n}")
    mean = float(np.mean(d))
    test = t_test_from_moments(n, mean, float(np.var(d, ddof=1)))
    if test.sd == 0.0:
        d_z = test.t  # +inf, -inf, or nan when every d = 0
    else:
        d_z = mean / test.sd
    d_z_low, d_z_high = effect_size_interval(test.t, n)
    notes = [test.note] if test.note else []
    if test.sd == 0.0:  # every resample has the same mean
        mean_low = mean_high = mean
    elif bootstrap:
        mean_low, mean_high = _bootstrap_mean_interval(d, bootstrap, seed)
    else:
        mean_low = mean_high = math.nan
        notes.append("bootstrap interval of M not computed (bootstrap=0)")
    return PairedTestResult(
        n=n,
        relative_surprise=mean,
        sd=test.sd,
        t=test.t,
        df=test.df,
        p_value=test.p_value,
        significant=bool(test.p_value < alpha),
        alpha=alpha,
        d_z=d_z,
        d_z_ci_low=d_z_low,
        d_z_ci_high=d_z_high,
        accuracy=float(np.mean(d > 0)),
        auroc=ranked_auroc(inc, con),
        relative_surprise_ci_low=mean_low,
        relative_surprise_ci_high=mean_high,
        note="; ".join(notes),
    )


class PairedSurpriseStats(Metric):
    """Streaming paired t-test for training-time callbacks: keeps n, sum d, sum d^2 and the
    count of d > 0 as float64 sum-states, so a DDP reduction (or ``merge_state``) gives the
    same result as one pass over all pairs. ``compute()`` returns float64 scalar tensors
    ``relative_surprise`` (mean d), ``t``, ``p_value`` (one-tailed, scipy's t distribution),
    ``accuracy`` (share of d > 0) and ``n``."""

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
            self.add_state(name, default=torch.zeros((), dtype=torch.float64),
                           dist_reduce_fx="sum")

    def update(
        self, surprise_inconsistent: torch.Tensor, surprise_consistent: torch.Tensor
    ) -> None:
        """Add a batch of pairs: per-video surprise [B] of the inconsistent and consistent video."""
        inc = torch.as_tensor(surprise_inconsistent).detach()
        con = torch.as_tensor(surprise_consistent).detach()
        if inc.ndim != 1 or inc.shape != con.shape:
            raise ValueError(
                "update expects per-video surprise of shape [B] for both videos of each pair; "
                f"got inconsistent {tuple(inc.shape)} and consistent {tuple(con.shape)}"
            )
        d = inc.to(device=self.sum_d.device, dtype=torch.float64) - con.to(
            device=self.sum_d.device, dtype=torch.float64)
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
            raise ValueError(f"PairedSurpriseStats needs at least 2 probe pairs, got n={n}")
        mean = float(self.sum_d) / n
        variance = max(0.0, (float(self.sum_d_squared) - n * mean * mean) / (n - 1))
        test = t_test_from_moments(n, mean, variance)
        values = {
            "relative_surprise": test.mean,
            "t": test.t,
            "p_value": test.p_value,
            "accuracy": float(self.positive) / n,
            "n": float(n),
        }
        return {key: torch.tensor(value, dtype=torch.float64) for key, value in values.items()}



# ----------------------------------------------------------------------------- groups and verdicts


def pair_groups(
    concepts: Sequence[str], variants: Sequence[str], pooled: bool = True
) -> list[tuple[str, str, np.ndarray]]:
    """(concept, variant, boolean row selector) for every concept/variant among the pairs, in
    ``specs`` order where known (others after, in order of first appearance). With ``pooled``,
    a concept holding both ``standard`` and ``counterbalanced`` pairs gets a ``pooled`` group
    (the union of the two) right after its variants."""
    concepts = np.asarray(concepts, dtype=object)
    variants = np.asarray(variants, dtype=object)
    keys = list(dict.fromkeys(zip(concepts.tolist(), variants.tolist())))

    def order(key: tuple[str, str]) -> tuple[int, int, int]:
        concept, variant = key
        return (specs.CONCEPTS.index(concept) if concept in specs.CONCEPTS else len(specs.CONCEPTS),
                specs.VARIANTS.index(variant) if variant in specs.VARIANTS else len(specs.VARIANTS),
                keys.index(key))

    groups = []
    ordered = sorted(keys, key=order)
    for concept in dict.fromkeys(concept for concept, _ in ordered):
        in_concept = concepts == concept
        present = [variant for c, variant in ordered if c == concept]
        groups.extend((concept, variant, in_concept & (variants == variant)) for variant in present)
        if pooled and set(POOLED_VARIANTS) <= set(present):
            groups.append((concept, POOLED, in_concept & np.isin(variants, POOLED_VARIANTS)))
    return groups


@dataclass(frozen=True)
class Verdict:
    """Whether a concept shows VOE by the rule of DESIGN.md §4: ``voe`` is True or False, or
    None when the pairs needed to decide are missing; ``reason`` names what failed."""

    concept: str
    voe: bool | None
    rule: str
    reason: str

    def text(self) -> str:
        if self.voe:
            return "VOE"
        return ("undecided: " if self.voe is None else "no VOE: ") + self.reason


def _p(p: float) -> str:
    return f"{p:.3f}".lstrip("0") if p >= 0.001 else "< .001"


def concept_verdicts(
    results: Mapping[tuple[str, str], Mapping[str, Any]] | Sequence[Mapping[str, Any]],
    alpha: float = 0.05,
) -> list[Verdict]:
    """Per concept, in the order first seen: VOE only when the pooled test is significant
    (p < alpha) and both pooled variants have M > 0, for a concept with a counterbalanced
    pair; otherwise (unchangeableness' position/color/shape, a benchmark's own variants) only
    when every one of its probe variants is significant. Generalization variants do not
    enter. ``results`` maps (concept, variant) to a dict with ``p_value`` and
    ``relative_surprise`` (None when untested), or is a list of rows that carry both names."""
    if not isinstance(results, Mapping):
        results = {(row["concept"], row["variant"]): row for row in results}
    verdicts = []
    for concept in dict.fromkeys(concept for concept, _ in results):
        present = [v for c, v in results if c == concept and v != POOLED]
        required = list(specs.STANDARD_VARIANTS.get(concept, present))
        if set(POOLED_VARIANTS) <= set(required):
            rule = "pooled p < alpha and M > 0 in both standard and counterbalanced"
            needed = [(concept, variant) for variant in POOLED_VARIANTS] + [(concept, POOLED)]
        else:
            rule = f"p < alpha in every variant ({', '.join(required)})"
            needed = [(concept, variant) for variant in required]
        untested = [variant for _, variant in needed
                    if results.get((concept, variant), {}).get("p_value") is None]
        if untested:
            verdicts.append(Verdict(concept, None, rule,
                                    f"no test of {', '.join(untested)} (needs >= 2 pairs each)"))
            continue
        failed = []
        for _, variant in needed:
            values = results[(concept, variant)]
            if variant in POOLED_VARIANTS and rule.startswith("pooled"):
                if not values["relative_surprise"] > 0:
                    failed.append(f"{variant} M = {values['relative_surprise']:.3g} <= 0")
            elif not values["p_value"] < alpha:
                failed.append(f"{variant} p = {_p(values['p_value'])} >= {alpha:g}")
        verdicts.append(Verdict(concept, not failed, rule, "; ".join(failed)))
    return verdicts


def json_row(row: Mapping[str, Any]) -> dict[str, Any]:
    """A statistics row as strict JSON: non-finite floats become the strings 'inf', '-inf' and
    'nan' (``float()`` reads them back; the row's note says why they are not finite)."""
    def value(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        return v
    return {key: value(v) for key, v in row.items()}
