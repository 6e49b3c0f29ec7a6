"""Calibration of the VOE verdict (docs/architecture.md §8): how often it says VOE for a model that
has no physics, only a physics-blind cue, and how large a true effect it needs to say VOE reliably.

A synthetic model's relative surprise of probe pair i of a concept is

    d_i = delta + weight * sign * follow(cue scores of pair i) + noise_i,   noise_i ~ N(0, 1),

built from the *real* cue scores of generated probes (``cues.CueAudit``, the frame-local cues):
``follow`` is one of ``cue_followers.FOLLOWERS``, linear or not, of the pair's cue difference or
of each video's score, scaled to unit SD over the concept's pairs; ``sign`` says which way the
model follows the cue; ``delta`` (in noise SDs) is a true violation effect. Each repetition draws
``pairs`` pairs per variant (with replacement, from the audit's pairs of that variant) and new
noise, tests every variant as reports do (``statistics``) and applies the verdict rule
(``verdicts.verdict_rule``). A quadruplet concept (``specs.QUADRUPLETS``)
draws whole quadruplets instead, each half's d as above, and applies the quadruplet test and
``verdicts.quadruplet_rule`` to D, the sum of its halves, for each of its quadruplets (VOE when
all pass: unchangeableness has one per change): a follower of cue scores that read only the
frames from the change frame on has opposite terms in the two halves, so D is noise.
With delta = 0 the rate
of VOE verdicts is the false-VOE rate, which must stay at or below alpha; over a grid of delta
the rate is the verdict's power. The same draws serve every delta (delta only shifts each
variant's mean), so the power curve is one simulation.

``python -m voe_lightning analyze calibrate --root DIR`` prints the table (docs/calibration.md).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy import stats

from voe_lightning import specs
from voe_lightning.audit import cues, video_cues
from voe_lightning.audit.cue_followers import FOLLOWERS
from voe_lightning.stats import statistics
from voe_lightning.stats.statistics_format import format_alpha, json_row
from voe_lightning.stats.t_tests import t_and_p
from voe_lightning.stats.verdicts import quadruplet_rule, quadruplets, verdict_rule

__all__ = [
    "DELTAS",
    "WEIGHTS",
    "CalibrationRow",
    "calibrate",
    "calibrate_store",
    "calibration_markdown",
    "cue_terms",
    "false_voe_bound",
    "quadruplet_voe",
    "rows_as_dicts",
    "verdict_rates",
]

#: The cue term's SD over a concept's pairs, in noise SDs.
WEIGHTS: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0)
#: The true effects (noise SDs) at which power is computed.
DELTAS: np.ndarray = np.round(np.arange(0.0, 3.0001, 0.02), 2)


def cue_terms(
    audit: cues.CueAudit, concept: str, cue: str, follower: str
) -> dict[str, np.ndarray] | None:
    """Per variant of ``concept`` (its verdict's variants), the follower's term of each of the
    audit's pairs, scaled to unit SD over all those pairs; None where the cue is not scored for
    every pair or does not vary (nothing to follow). For a quadruplet concept, the two
    halves' terms of each quadruplet are aligned by seed (``verdicts.quadruplets``)."""
    variants = specs.VERDICT_VARIANTS.get(concept, ())
    rows = (audit.concepts == concept) & np.isin(audit.variants, variants)
    con = audit.scores["consistent"][cue][rows]
    inc = audit.scores["inconsistent"][cue][rows]
    if not rows.any() or np.isnan(con).any() or np.isnan(inc).any():
        return None
    both = np.concatenate([con, inc])
    difference_scale, score_scale = float(np.std(inc - con)), float(np.std(both))
    if difference_scale == 0.0 or score_scale == 0.0:
        return None
    term = FOLLOWERS[follower](con, inc, difference_scale, score_scale, float(np.mean(both)))
    spread = float(np.std(term))
    if spread == 0.0:
        return None
    term = term / spread
    if concept in specs.QUADRUPLET_CONCEPTS:
        every = np.full(len(audit), np.nan)
        every[rows] = term
        return {
            variant: every[half]
            for row, halves in specs.QUADRUPLETS[concept].items()
            for variant, half in zip(halves, _matched(audit, concept, row))
        }
    return {
        variant: term[audit.variants[rows] == variant]
        for variant in variants
        if (audit.variants[rows] == variant).any()
    }


def _matched(audit: cues.CueAudit, concept: str, row: str) -> tuple[np.ndarray, np.ndarray]:
    """The audit's pairs of ``concept``'s quadruplet ``row``, first halves and second halves
    aligned (``verdicts.quadruplets``); a ValueError when its pairs carry no seeds or match
    none."""
    if audit.seeds is None:
        raise ValueError(
            f"{concept} is tested over quadruplets, matched by seed, but the "
            "audited pairs carry no seeds"
        )
    found = [
        (first, second)
        for c, name, first, second in quadruplets(audit.concepts, audit.variants, audit.seeds)
        if (c, name) == (concept, row)
    ]
    if not found:
        halves = " and a ".join(specs.QUADRUPLETS[concept][row])
        raise ValueError(
            f"no {concept} {row}s among the audited pairs: no seed holds both a {halves} pair"
        )
    return found[0]


def verdict_rates(
    terms: Mapping[str, np.ndarray],
    concept: str,
    pairs: int,
    repetitions: int,
    alpha: float,
    deltas: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """The share of ``repetitions`` whose verdict for ``concept`` is VOE, at each of ``deltas``,
    for relative surprise delta + term + N(0, 1) per pair; ``terms`` per variant (all zero: pure
    noise). Each repetition resamples ``pairs`` pairs per variant (a quadruplet concept:
    ``pairs`` quadruplets of each of its quadruplets, VOE when all pass, ``quadruplet_voe``)."""
    variants = specs.VERDICT_VARIANTS[concept]
    missing = [variant for variant in variants if variant not in terms]
    if missing:
        raise ValueError(
            f"{concept} needs cue terms of every variant {variants}; missing {missing}"
        )
    if concept in specs.QUADRUPLET_CONCEPTS:
        every_passes: np.ndarray = np.all(
            [
                quadruplet_voe([terms[v] for v in halves], pairs, repetitions, alpha, deltas, rng)
                for halves in specs.QUADRUPLETS[concept].values()
            ],
            axis=0,
        ).mean(axis=1)
        return every_passes
    moments = {}
    for variant in variants:
        pool = terms[variant]
        d = pool[rng.integers(0, pool.size, (repetitions, pairs))]
        d = d + rng.standard_normal((repetitions, pairs))
        moments[variant] = (d.mean(axis=1), d.var(axis=1, ddof=1))
    shifted = np.asarray(deltas, dtype=np.float64)[:, None]  # [deltas, 1] over [repetitions]
    means = {variant: mean[None] + shifted for variant, (mean, _) in moments.items()}
    p_values = [t_and_p(means[v], np.sqrt(moments[v][1] / pairs), pairs - 1)[1] for v in variants]
    rates: np.ndarray = verdict_rule(p_values, alpha).mean(axis=1)
    return rates


def quadruplet_voe(
    halves: Sequence[np.ndarray],
    count: int,
    repetitions: int,
    alpha: float,
    deltas: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Whether one quadruplet's test says VOE [deltas, repetitions]: each repetition resamples
    ``count`` quadruplets (their two ``halves``' terms, aligned) and adds delta + N(0, 1) to
    each half's d; VOE by ``quadruplet_rule`` on D = the sum of the halves."""
    first, second = (np.asarray(half, dtype=np.float64) for half in halves)
    if first.shape != second.shape:
        raise ValueError(
            f"a quadruplet's two halves must align; got {first.size} first and "
            f"{second.size} second terms"
        )
    index = rng.integers(0, first.size, (repetitions, count))
    drawn = [half[index] + rng.standard_normal((repetitions, count)) for half in (first, second)]
    total = drawn[0] + drawn[1]
    shifted = np.asarray(deltas, dtype=np.float64)[:, None]  # [deltas, 1] over [repetitions]
    error = np.sqrt(total.var(axis=1, ddof=1) / count)
    p_values = t_and_p(total.mean(axis=1)[None] + 2 * shifted, error, count - 1)[1]
    first_mean, second_mean = (half.mean(axis=1)[None] + shifted for half in drawn)
    voe: np.ndarray = quadruplet_rule(p_values, first_mean, second_mean, alpha)
    return voe


@dataclass(frozen=True)
class CalibrationRow:
    """One synthetic model of one concept: which cue it follows (None: noise only), how
    (``follower``, ``sign``, ``weight``), its rate of VOE verdicts at delta = 0 (the false-VOE
    rate) and the smallest delta of the grid at which the rate reaches 80% (NaN if none; None
    where power was not computed), with the rate there. ``right_on_every_variant``: the cue term
    is positive on average in every variant of the audited pairs, so the follower looks like VOE
    to any test of d; no verdict can be calibrated against it (the stimuli's fault: the
    variants do not mirror this cue); otherwise the verdict rule holds it to alpha."""

    concept: str
    cue: str | None
    follower: str | None
    sign: int
    weight: float
    pairs: int
    repetitions: int
    alpha: float
    false_voe_rate: float
    delta_80: float | None
    power_at_delta_80: float | None
    right_on_every_variant: bool


def calibrate(
    audit: cues.CueAudit,
    pairs: int | None = None,
    repetitions: int = 2000,
    *,
    alpha: float,
    concepts: Sequence[str] | None = None,
    cue_names: Sequence[str] = video_cues.FRAME_LOCAL_CUES,
    followers: Sequence[str] = tuple(FOLLOWERS),
    weights: Sequence[float] = WEIGHTS,
    deltas: np.ndarray = DELTAS,
    power_weights: Sequence[float] = (1.0,),
    seed: int = 0,
) -> list[CalibrationRow]:
    """A ``CalibrationRow`` per concept of the audit (or ``concepts``) for noise alone and for
    each cue, follower, sign (+1, -1) and weight; ``pairs`` per variant per repetition
    (default: the audit's smallest variant; a quadruplet concept: its quadruplets). Power (over ``deltas``) is computed for noise
    alone and the ``power_weights``; the other rows have only the false-VOE rate (their
    ``delta_80`` is NaN). Seeded: the same arguments give the same rows."""
    statistics.check_alpha(alpha)
    if repetitions < 1:
        raise ValueError(f"repetitions must be >= 1, got {repetitions}")
    unknown = sorted(set(followers) - set(FOLLOWERS))
    if unknown:
        raise ValueError(f"unknown followers {unknown}; valid: {', '.join(FOLLOWERS)}")
    zero = np.zeros(1)
    grid_with_zero = np.unique(np.concatenate([zero, np.asarray(deltas, dtype=np.float64)]))
    chosen = set(concepts or audit.concepts.tolist())
    concepts = [concept for concept in specs.CONCEPTS if concept in chosen]  # specs order
    rows = []
    for concept in concepts:
        variants = specs.VERDICT_VARIANTS[concept]
        sizes = (
            {row: _matched(audit, concept, row)[0].size for row in specs.QUADRUPLETS[concept]}
            if concept in specs.QUADRUPLET_CONCEPTS
            else {
                v: int(((audit.concepts == concept) & (audit.variants == v)).sum())
                for v in variants
            }
        )
        if min(sizes.values()) < 2:
            raise ValueError(
                f"{concept} needs at least 2 audited pairs of each of {variants}; "
                f"the audit has {sizes}"
            )
        n = pairs or min(sizes.values())
        if n < 2:
            raise ValueError(f"pairs must be >= 2 per variant, got {pairs}")
        rng = np.random.default_rng([seed, specs.CONCEPTS.index(concept)])

        def row(
            cue: str | None,
            follower: str | None,
            sign: int,
            weight: float,
            terms: Mapping[str, np.ndarray],
            concept: str = concept,
            n: int = n,
            rng: np.random.Generator = rng,
        ) -> CalibrationRow:
            power = cue is None or weight in power_weights
            grid = grid_with_zero if power else zero
            rates = verdict_rates(terms, concept, n, repetitions, alpha, grid, rng)
            reached = np.flatnonzero(rates >= 0.8)
            delta_80 = power_80 = None
            if power:
                at = int(reached[0]) if reached.size else None
                delta_80 = float(grid[at]) if at is not None else math.nan
                power_80 = float(rates[at]) if at is not None else math.nan
            right = cue is not None and all(float(np.mean(term)) > 0 for term in terms.values())
            return CalibrationRow(
                concept,
                cue,
                follower,
                sign,
                weight,
                n,
                repetitions,
                alpha,
                float(rates[0]),
                delta_80,
                power_80,
                right,
            )

        rows.append(row(None, None, 1, 0.0, {v: np.zeros(1) for v in variants}))
        for cue in cue_names:
            for follower in followers:
                terms = cue_terms(audit, concept, cue, follower)
                if terms is None:
                    continue
                for sign in (1, -1):
                    for weight in weights:
                        rows.append(
                            row(
                                cue,
                                follower,
                                sign,
                                weight,
                                {v: sign * weight * term for v, term in terms.items()},
                            )
                        )
    return rows


def false_voe_bound(repetitions: int, alpha: float, tests: int = 1, error: float = 1e-3) -> float:
    """The largest false-VOE rate a calibrated verdict (true rate <= alpha) shows in
    ``repetitions`` with probability 1 - ``error`` over ``tests`` rates at once (Bonferroni):
    the binomial quantile, as a rate."""
    return float(stats.binom.ppf(1.0 - error / tests, repetitions, alpha)) / repetitions


def _power(row: CalibrationRow) -> str:
    """'δ (power there)' of a row, '> 3' beyond the grid, 'n/a' where not computed."""
    if row.delta_80 is None:
        return "n/a"
    if math.isnan(row.delta_80):
        return f"> {DELTAS[-1]:g}"
    assert row.power_at_delta_80 is not None  # computed with delta_80
    return f"{row.delta_80:.2f} ({100 * row.power_at_delta_80:.0f}%)"


def _delta_80(row: CalibrationRow) -> float:
    """A row's delta_80 to rank by, inf where 80% is never reached (NaN; None: not computed)."""
    return math.inf if row.delta_80 is None or math.isnan(row.delta_80) else row.delta_80


def _cue_title(row: CalibrationRow) -> str:
    assert row.cue is not None  # a row of a cue follower
    return cues.CUE_TITLES[row.cue]


def calibration_markdown(rows: Sequence[CalibrationRow], title: str = "Calibration") -> str:
    """The table of docs/calibration.md: per concept and follower, the worst false-VOE rate at
    delta = 0 over cues, signs and weights (and which), the binomial bound it must stay under,
    and the delta at which the verdict first says VOE in 80% of repetitions (with the power
    there) for noise alone and for the worst cue and sign at weight 1."""
    if not rows:
        raise ValueError("no calibration rows to tabulate")
    alpha, repetitions = rows[0].alpha, rows[0].repetitions
    tested = [row for row in rows if row.cue is not None]
    bound = false_voe_bound(repetitions, alpha, max(1, len(rows)))
    lines = [
        f"## {title} ({format_alpha(alpha)}, {repetitions} repetitions)",
        "",
        "| concept | pairs per variant (quadruplets) | cue follower | false VOE at δ = 0: worst (cue, "
        "sign, weight) | δ (power) at 80% VOE: noise only | δ (power) at 80% VOE: worst "
        "cue at weight 1 (cue, sign) |",
        "|" + "---|" * 6,
    ]
    for concept in dict.fromkeys(row.concept for row in rows):
        noise = next(row for row in rows if row.concept == concept and row.cue is None)
        for follower in dict.fromkeys(row.follower for row in tested if row.concept == concept):
            mine = [row for row in tested if (row.concept, row.follower) == (concept, follower)]
            worst = max(mine, key=lambda row: row.false_voe_rate)
            at_one = [row for row in mine if row.weight == 1.0 and row.delta_80 is not None]
            hardest = max(at_one, key=_delta_80) if at_one else None
            hard = (
                "n/a"
                if hardest is None
                else f"{_power(hardest)} ({_cue_title(hardest)}, {hardest.sign:+d})"
            )
            false_voe = f"{100 * worst.false_voe_rate:.2f}%"
            if worst.false_voe_rate > 0:
                false_voe += (
                    (" †" if worst.right_on_every_variant else "")
                    + (" **> bound**" if worst.false_voe_rate > bound else "")
                    + f" ({_cue_title(worst)}, {worst.sign:+d}, "
                    f"{worst.weight:g})"
                )
            lines.append(
                f"| {concept} | {noise.pairs} | {follower} | {false_voe} "
                f"| {_power(noise)} | {hard} |"
            )
    lines += [
        "",
        f"Synthetic relative surprise d = δ + weight · sign · f(cue) + N(0, 1) per pair "
        "(δ and weight in noise SDs; f scaled to unit SD over the concept's pairs), from "
        "the real cue scores of the audited probes; each repetition resamples the pairs "
        "of each variant and tests as the report does (verdict: `verdicts.verdict_rule`; "
        "a quadruplet concept resamples its quadruplets and decides by the quadruplet "
        "test, `verdicts.quadruplet_rule`). "
        f"False VOE must stay at or below α; with {repetitions} repetitions and "
        f"{len(rows)} rates, {100 * bound:.2f}% is the binomial bound (p = .001, "
        "Bonferroni) a calibrated verdict stays under. δ: the smallest of a grid of "
        "steps of 0.02 at which the verdict says VOE in at least 80% of repetitions, "
        "and that share. †: the cue term is positive on average in every variant of "
        "these pairs (the variants do not mirror the cue), so the follower looks like VOE "
        "to any test of d: the stimuli's fault, not the verdict's.",
    ]
    return "\n".join(lines) + "\n"


def rows_as_dicts(rows: Sequence[CalibrationRow]) -> list[dict[str, Any]]:
    """The rows as plain dicts (JSON)."""
    return [json_row(vars(row)) for row in rows]


# ----------------------------------------------------------------------------- command line


def calibrate_store(
    root: Path,
    split: Literal["val", "test"] = "test",
    concepts: list[specs.Concept] | None = None,
    pairs: int | None = None,
    repetitions: int = 2000,
    *,
    alpha: float,
    seed: int = 0,
    out: Path | None = None,
    batch_size: int = 64,
    num_workers: int = 0,
    progress: bool = True,
) -> str:
    """Calibration of the VOE verdict on synthetic cue-following surprise, as a Markdown table.

    Scores the cues of a probe split (as ``audit`` does), then simulates models that follow
    them without physics (``voe_lightning.audit.calibration``): the false-VOE rate at no effect and
    the effect at which the verdict says VOE in 80% of repetitions, per concept and follower.

    Args:
        root: dataset folder (a generated store).
        split: probe split whose pairs give the cue scores.
        concepts: concepts to calibrate (default: every concept in the store).
        pairs: pairs per variant in each repetition (default: all the split has).
        repetitions: simulated experiments per synthetic model.
        alpha: significance level (default: configs/base.yaml's alpha).
        seed: seed of the simulation.
        out: also write the table here, and every row as JSON beside it (.json).
        batch_size: pairs scored at once.
        num_workers: data loader worker processes.
        progress: show a progress bar while scoring.
    """
    audit = cues.audit_split(root, split, concepts, batch_size, num_workers, progress=progress)
    rows = calibrate(audit, pairs=pairs, repetitions=repetitions, alpha=alpha, seed=seed)
    table = calibration_markdown(rows, title=f"Calibration on the {split} pairs of {root}")
    print(table, end="")
    if out:
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(table)
        out.with_suffix(".json").write_text(json.dumps(rows_as_dicts(rows), indent=2) + "\n")
    return table
