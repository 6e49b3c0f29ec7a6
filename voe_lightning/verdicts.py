"""Which rows a VOE table has and the verdict they give (docs/architecture.md §8): every
concept/variant among the probe pairs, plus a ``pooled`` row for a concept with a standard and
a counterbalanced variant (``pair_groups``) and, for a concept whose two variants are the
halves of one quadruplet per seed, its quadruplets (``quadruplets``); and per concept, whether
it shows VOE (``concept_verdicts``: the quadruplet test with both halves above 0 where there is
one, else every test its verdict reads significant at alpha, ``verdict_rule``).
The tests themselves are in ``voe_lightning.statistics``; the verdict's calibration in
``voe_lightning.calibration``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from voe_lightning import specs
from voe_lightning.causality import NOT_CAUSAL, Causality
from voe_lightning.statistics import ALPHA, POOLED, POOLED_VARIANTS, QUADRUPLET, check_alpha
from voe_lightning.statistics_format import format_number, format_p

__all__ = ["Verdict", "concept_verdicts", "pair_groups", "quadruplet_rule", "quadruplets",
           "verdict_rule"]


def pair_groups(
    concepts: Sequence[str], variants: Sequence[str], pooled: bool = True,
    seeds: Sequence[int] | None = None,
) -> list[tuple[str, str, np.ndarray]]:
    """(concept, variant, row selector) for every concept/variant among the pairs, in
    ``specs`` order where known (others after, in order of first appearance); selectors are
    boolean masks. With ``pooled``, a concept holding both ``standard`` and ``counterbalanced``
    pairs gets a ``pooled`` group (the pairs of both, tested by ``pooled_test``) right after its
    variants; with ``seeds`` too, a quadruplet concept then gets a ``quadruplet`` group whose
    selector is an index array, its matched first halves then its second halves in seed order
    (``quadruplets``; tested by ``quadruplet_test``)."""
    concepts = np.asarray(concepts, dtype=object)
    variants = np.asarray(variants, dtype=object)
    keys = list(dict.fromkeys(zip(concepts.tolist(), variants.tolist())))

    def order(key: tuple[str, str]) -> tuple[int, int, int]:
        concept, variant = key
        return (specs.CONCEPTS.index(concept) if concept in specs.CONCEPTS else len(specs.CONCEPTS),
                specs.VARIANTS.index(variant) if variant in specs.VARIANTS else len(specs.VARIANTS),
                keys.index(key))

    matched = ({concept: np.concatenate([first, second]) for concept, first, second
                in quadruplets(concepts, variants, seeds)} if pooled and seeds is not None else {})
    groups = []
    ordered = sorted(keys, key=order)
    for concept in dict.fromkeys(concept for concept, _ in ordered):
        in_concept = concepts == concept
        present = [variant for c, variant in ordered if c == concept]
        groups.extend((concept, variant, in_concept & (variants == variant)) for variant in present)
        if pooled and set(POOLED_VARIANTS) <= set(present):
            groups.append((concept, POOLED, in_concept & np.isin(variants, POOLED_VARIANTS)))
        if concept in matched:
            groups.append((concept, QUADRUPLET, matched[concept]))
    return groups


def quadruplets(concepts: Sequence[str], variants: Sequence[str], seeds: Sequence[int]
                ) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(concept, first, second) for every concept among the pairs whose standard (first half)
    and counterbalanced (second half) pairs share seeds: the row indices of both halves of
    every seed both hold, in seed order; a seed names a quadruplet. Ours are the concepts of
    ``specs.QUADRUPLET_CONCEPTS``; a benchmark's reader names its quadruplets' halves so too
    (docs/benchmarks.md). A seed twice in one variant is refused (two splits mixed)."""
    concepts, variants = (np.asarray(x, dtype=object) for x in (concepts, variants))
    seeds = np.asarray(seeds, dtype=np.int64)
    matched = []
    for concept in dict.fromkeys(concepts[np.isin(variants, POOLED_VARIANTS)].tolist()):
        halves = []
        for variant in POOLED_VARIANTS:
            rows = np.flatnonzero((concepts == concept) & (variants == variant))
            unique, counts = np.unique(seeds[rows], return_counts=True)
            if (counts > 1).any():
                raise ValueError(f"{concept}/{variant} holds seed {int(unique[counts > 1][0])} "
                                 "more than once: a seed must name one quadruplet")
            halves.append(dict(zip(seeds[rows].tolist(), rows.tolist())))
        common = sorted(set(halves[0]) & set(halves[1]))
        if common:
            matched.append((concept, np.array([halves[0][s] for s in common], dtype=np.int64),
                            np.array([halves[1][s] for s in common], dtype=np.int64)))
    return matched


@dataclass(frozen=True)
class Verdict:
    """Whether a concept shows VOE by the rule of docs/architecture.md §8: ``voe`` is True or
    False, or None when the pairs needed to decide are missing or the verdict is ``withheld``
    (the model is not causal, ``voe_lightning.causality``); ``reason`` names what failed."""

    concept: str
    voe: bool | None
    rule: str
    reason: str
    withheld: bool = False

    def text(self) -> str:
        if self.withheld:
            return "no verdict: " + self.reason
        if self.voe:
            return "VOE"
        return ("undecided: " if self.voe is None else "no VOE: ") + self.reason


def verdict_rule(p_values: Sequence[Any], alpha: float) -> Any:
    """VOE when every test a concept's verdict reads has p < alpha (``p_values`` one per test
    along axis 0; arrays broadcast over the rest, as the calibration's repetitions). For a
    concept with a counterbalanced pair these are the stratified pooled test and each variant's
    own: requiring each variant significant, not only M > 0, is an intersection-union test, so
    a model that follows a cue pointing the wrong way in one variant says VOE in at most alpha
    of repetitions (``voe_lightning.calibration``); M > 0 alone lets it through whenever noise
    lifts that variant's M above zero."""
    return np.all(np.asarray(p_values, dtype=np.float64) < alpha, axis=0)


def quadruplet_rule(p_value: Any, first_half: Any, second_half: Any, alpha: float) -> Any:
    """VOE when the quadruplet test has p < alpha and both halves' mean differences are above 0
    (arrays broadcast, as the calibration's repetitions): a model whose surprise only rises in
    one half, the violation that adds an object or the one that removes it, shows no VOE."""
    return ((np.asarray(p_value, dtype=np.float64) < alpha) & (np.asarray(first_half) > 0)
            & (np.asarray(second_half) > 0))


def _quadruplet_verdict(concept: str, row: Mapping[str, Any], alpha: float) -> Verdict:
    """The verdict of a concept from its quadruplet row (``quadruplet_rule``)."""
    rule = f"p < {alpha:g} in the quadruplet test, both halves M > 0"
    if row.get("p_value") is None:
        return Verdict(concept, None, rule, "no quadruplet test (needs >= 2 quadruplets)")
    p_value, halves = row["p_value"], (row["first_half"], row["second_half"])
    failed = [f"{name} half M = {format_number(mean)} <= 0"
              for name, mean in zip(POOLED_VARIANTS, halves) if not mean > 0]
    if not p_value < alpha:
        failed.insert(0, f"quadruplet p = {format_p(p_value)} >= {alpha:g}")
    voe = bool(quadruplet_rule(p_value, *halves, alpha))
    return Verdict(concept, voe, rule, "" if voe else "; ".join(failed))


def concept_verdicts(
    results: Mapping[tuple[str, str], Mapping[str, Any]] | Sequence[Mapping[str, Any]],
    alpha: float = ALPHA,
    causality: Causality | None = None,
) -> list[Verdict]:
    """Per concept, in the order first seen: ``quadruplet_rule`` on its ``quadruplet`` row
    where it has one (a report's rows; the training-time table, which pairs no seeds, has
    none), else ``verdict_rule`` over the tests it reads: for a
    concept with a counterbalanced pair, the pooled test and both variants; otherwise
    (unchangeableness' position/color/shape, a benchmark's own variants) every one of its
    probe variants. Generalization variants do not enter. ``results`` maps (concept, variant)
    to a dict with ``p_value`` and ``relative_surprise`` (None when untested), or is a list of
    rows that carry both names. A ``causality`` check that failed withholds every verdict."""
    check_alpha(alpha)
    if not isinstance(results, Mapping):
        results = {(row["concept"], row["variant"]): row for row in results}
    verdicts = []
    for concept in dict.fromkeys(concept for concept, _ in results):
        if (concept, QUADRUPLET) in results:
            verdicts.append(_quadruplet_verdict(concept, results[(concept, QUADRUPLET)], alpha))
            continue
        present = [v for c, v in results if c == concept and v not in (POOLED, QUADRUPLET)]
        required = list(specs.VERDICT_VARIANTS.get(concept, present))
        if set(POOLED_VARIANTS) <= set(required):
            rule = (f"p < {alpha:g} in the stratified pooled test and in both standard and "
                    "counterbalanced")
            needed = [*POOLED_VARIANTS, POOLED]
        else:
            rule = f"p < {alpha:g} in every variant ({', '.join(required)})"
            needed = required
        untested = [variant for variant in needed
                    if results.get((concept, variant), {}).get("p_value") is None]
        if untested:
            verdicts.append(Verdict(concept, None, rule,
                                    f"no test of {', '.join(untested)} (needs >= 2 pairs each)"))
            continue
        values = {variant: results[(concept, variant)] for variant in needed}
        voe = bool(verdict_rule([values[variant]["p_value"] for variant in needed], alpha))
        failed = []
        for variant in needed:
            p_value, mean = values[variant]["p_value"], values[variant]["relative_surprise"]
            if not mean > 0:
                failed.append(f"{variant} M = {format_number(mean)} <= 0")
            elif not p_value < alpha:
                failed.append(f"{variant} p = {format_p(p_value)} >= {alpha:g}")
        verdicts.append(Verdict(concept, voe, rule, "" if voe else "; ".join(failed)))
    if causality is not None and not causality.causal:
        return [Verdict(v.concept, None, v.rule, NOT_CAUSAL, withheld=True) for v in verdicts]
    return verdicts
