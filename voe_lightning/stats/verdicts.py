"""Which rows a VOE table has and the verdict they give (docs/architecture.md §8): every
concept/variant among the probe pairs, plus a ``pooled`` row for a concept with a standard and
a counterbalanced variant (``pair_groups``) and, for each quadruplet of a concept whose variants
are the halves of quadruplets, one per seed (``specs.QUADRUPLETS``), its quadruplet row
(``quadruplets``); and per concept, whether it shows VOE (``concept_verdicts``: each of its
quadruplet tests with both halves above 0 where it has them, else every test its verdict reads
significant at alpha, ``verdict_rule``).
The tests themselves are in ``voe_lightning.stats.statistics``; the verdict's calibration in
``voe_lightning.audit.calibration``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from voe_lightning import specs
from voe_lightning.stats import causality as causality_check
from voe_lightning.stats.statistics import POOLED, POOLED_VARIANTS, check_alpha
from voe_lightning.stats.statistics_format import (
    format_number,
    format_p,
    format_p_phrase,
    format_t,
)

__all__ = [
    "Verdict",
    "concept_verdicts",
    "pair_groups",
    "quadruplet_rule",
    "quadruplets",
    "verdict_rule",
]


def pair_groups(
    concepts: Sequence[str] | np.ndarray,
    variants: Sequence[str] | np.ndarray,
    pooled: bool = True,
    seeds: Sequence[int] | np.ndarray | None = None,
) -> list[tuple[str, str, np.ndarray]]:
    """(concept, variant, row selector) for every concept/variant among the pairs, in
    ``specs`` order where known (others after, in order of first appearance); selectors are
    boolean masks. With ``pooled``, a concept holding both ``standard`` and ``counterbalanced``
    pairs gets a ``pooled`` group (the pairs of both, tested by ``pooled_test``) right after its
    variants; with ``seeds`` too, each quadruplet of a concept (``specs.QUADRUPLETS``) then gets
    a group named by its row, whose selector is an index array, its matched first halves then
    its second halves in seed order (``quadruplets``; tested by ``quadruplet_test``)."""
    concept_of = np.asarray(concepts, dtype=object)
    variant_of = np.asarray(variants, dtype=object)
    keys = list(dict.fromkeys(zip(concept_of.tolist(), variant_of.tolist())))

    def order(key: tuple[str, str]) -> tuple[int, int, int]:
        concept, variant = key
        return (
            specs.CONCEPTS.index(concept) if concept in specs.CONCEPTS else len(specs.CONCEPTS),
            specs.VARIANTS.index(variant) if variant in specs.VARIANTS else len(specs.VARIANTS),
            keys.index(key),
        )

    matched = (
        [
            (concept, row, np.concatenate([first, second]))
            for concept, row, first, second in quadruplets(concept_of, variant_of, seeds)
        ]
        if pooled and seeds is not None
        else []
    )
    groups: list[tuple[str, str, np.ndarray]] = []
    ordered = sorted(keys, key=order)
    for concept in dict.fromkeys(concept for concept, _ in ordered):
        in_concept = concept_of == concept
        present = [variant for c, variant in ordered if c == concept]
        groups.extend(
            (concept, variant, in_concept & (variant_of == variant)) for variant in present
        )
        if pooled and set(POOLED_VARIANTS) <= set(present):
            groups.append((concept, POOLED, in_concept & np.isin(variant_of, POOLED_VARIANTS)))
        groups.extend((c, row, rows) for c, row, rows in matched if c == concept)
    return groups


def quadruplets(
    concepts: Sequence[str] | np.ndarray,
    variants: Sequence[str] | np.ndarray,
    seeds: Sequence[int] | np.ndarray,
) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """(concept, row, first, second) for every quadruplet among the pairs: the row indices of its
    first-half (A, AB) and second-half (B, BA) pairs of every seed both hold, in seed order; a
    seed names a quadruplet. Ours are ``specs.QUADRUPLETS``; any other concept (a benchmark's,
    whose reader names its quadruplets' halves so, docs/benchmarks.md) has one, row
    ``quadruplet``, where its standard and counterbalanced pairs share seeds. A seed twice in
    one variant is refused (the pairs of two splits mixed)."""
    concept_of, variant_of = (np.asarray(x, dtype=object) for x in (concepts, variants))
    seed_of = np.asarray(seeds, dtype=np.int64)
    present = list(dict.fromkeys(concept_of.tolist()))
    ours = [c for c in specs.QUADRUPLETS if c in present]
    matched = []
    for concept in ours + [c for c in present if c not in specs.QUADRUPLETS]:
        for row, halves in quadruplets_of(concept).items():
            by_seed = [_rows_by_seed(concept_of, variant_of, seed_of, concept, v) for v in halves]
            common = sorted(set(by_seed[0]) & set(by_seed[1]))
            if common:
                matched.append(
                    (
                        concept,
                        row,
                        *(np.array([half[s] for s in common], dtype=np.int64) for half in by_seed),
                    )
                )
    return matched


def quadruplets_of(concept: str) -> dict[str, tuple[str, str]]:
    """A concept's quadruplets, row name -> its two halves: ours from ``specs.QUADRUPLETS``,
    any other concept's (a benchmark's) one ``quadruplet`` of its standard and counterbalanced
    pairs."""
    return specs.QUADRUPLETS.get(concept, {specs.QUADRUPLET: specs.QUADRUPLET_VARIANTS})


def _rows_by_seed(
    concepts: np.ndarray, variants: np.ndarray, seeds: np.ndarray, concept: str, variant: str
) -> dict[int, int]:
    """seed -> row index of ``concept``'s ``variant`` pairs; a ValueError on a repeated seed."""
    rows = np.flatnonzero((concepts == concept) & (variants == variant))
    unique, counts = np.unique(seeds[rows], return_counts=True)
    if (counts > 1).any():
        raise ValueError(
            f"{concept}/{variant} holds seed {int(unique[counts > 1][0])} "
            "more than once: a seed must name one quadruplet"
        )
    return dict(zip(seeds[rows].tolist(), rows.tolist()))


@dataclass(frozen=True)
class Verdict:
    """Whether a concept shows VOE by the rule of docs/architecture.md §8: ``voe`` is True or
    False, or None when the pairs needed to decide are missing or the verdict is ``withheld``
    (the model is not causal, ``voe_lightning.stats.causality``); ``reason`` names what failed."""

    concept: str
    voe: bool | None
    rule: str
    reason: str
    withheld: bool = False
    #: Whether every quadruplet half is significant on its own at alpha (its variant's own
    #: paired test): stricter than the verdict's rule; None without quadruplets or tests.
    halves_significant: bool | None = None
    #: Each half's own test, e.g. "standard t(199) = 41.50, p < .001; counterbalanced ...".
    halves: str = ""

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
    of repetitions (``voe_lightning.audit.calibration``); M > 0 alone lets it through whenever noise
    lifts that variant's M above zero."""
    return np.all(np.asarray(p_values, dtype=np.float64) < alpha, axis=0)


def quadruplet_rule(p_value: Any, first_half: Any, second_half: Any, alpha: float) -> Any:
    """VOE when the quadruplet test has p < alpha and both halves' mean differences are above 0
    (arrays broadcast, as the calibration's repetitions): a model whose surprise only rises in
    one half, the violation that adds an object or the one that removes it, shows no VOE."""
    return (
        (np.asarray(p_value, dtype=np.float64) < alpha)
        & (np.asarray(first_half) > 0)
        & (np.asarray(second_half) > 0)
    )


def _quadruplet_verdict(
    concept: str, results: Mapping[tuple[str, str], Mapping[str, Any]], alpha: float
) -> Verdict:
    """The verdict of a concept from its quadruplet rows (``quadruplet_rule`` on each of
    ``specs.QUADRUPLETS[concept]``; all must pass)."""
    rows = quadruplets_of(concept)
    several = len(rows) > 1
    rule = (
        f"p < {alpha:g} in the quadruplet test{' of each change' if several else ''}, "
        "both halves M > 0"
    )
    untested = [row for row in rows if results.get((concept, row), {}).get("p_value") is None]
    if untested:
        return Verdict(
            concept, None, rule, f"no test of {', '.join(untested)} (needs >= 2 quadruplets each)"
        )
    failed, voe = [], True
    for row, halves in rows.items():
        p_value = results[(concept, row)]["p_value"]
        means = (results[(concept, row)]["first_half"], results[(concept, row)]["second_half"])
        voe &= bool(quadruplet_rule(p_value, *means, alpha))
        if not p_value < alpha:
            failed.append(f"{row} p = {format_p(p_value, alpha)} >= {alpha:g}")
        failed += [
            f"{name} half M = {format_number(mean)} <= 0"
            for name, mean in zip(halves, means)
            if not mean > 0
        ]
    significant, halves_alone = _halves_on_their_own(concept, results, alpha)
    return Verdict(
        concept, voe, rule, "" if voe else "; ".join(failed), False, significant, halves_alone
    )


def _halves_on_their_own(
    concept: str, results: Mapping[tuple[str, str], Mapping[str, Any]], alpha: float
) -> tuple[bool | None, str]:
    """Whether each half of each of ``concept``'s quadruplets is significant at ``alpha`` by
    its own paired test (its variant's row), and the text of those tests; (None, '') where a
    half has no test."""
    tests = []
    for halves in quadruplets_of(concept).values():
        for half in halves:
            row = results.get((concept, half), {})
            if row.get("p_value") is None:
                return None, ""
            tests.append((half, row))
    text = "; ".join(
        f"{half} {format_t(row.get('t'), row.get('df'))}, {format_p_phrase(row['p_value'], alpha)}"
        for half, row in tests
    )
    return all(row["p_value"] < alpha for _, row in tests), text


def concept_verdicts(
    results: Mapping[tuple[str, str], Mapping[str, Any]] | Sequence[Mapping[str, Any]],
    alpha: float,
    causality: causality_check.Causality | None = None,
) -> list[Verdict]:
    """Per concept, in the order first seen: ``quadruplet_rule`` on each of its quadruplet rows
    where it has any (a report's rows; the training-time table, which pairs no seeds, has
    none), else ``verdict_rule`` over the tests it reads: for a
    concept with a counterbalanced pair, the pooled test and both variants; otherwise
    (unchangeableness' six halves, a benchmark's own variants) every one of its
    probe variants. Generalization variants do not enter. ``results`` maps (concept, variant)
    to a dict with ``p_value`` and ``relative_surprise`` (None when untested), or is a list of
    rows that carry both names. A ``causality`` check that failed withholds every verdict."""
    check_alpha(alpha)
    if not isinstance(results, Mapping):
        results = {(row["concept"], row["variant"]): row for row in results}
    verdicts = []
    for concept in dict.fromkeys(concept for concept, _ in results):
        if any((concept, row) in results for row in quadruplets_of(concept)):
            verdicts.append(_quadruplet_verdict(concept, results, alpha))
            continue
        present = [v for c, v in results if c == concept and v != POOLED]
        required = list(specs.VERDICT_VARIANTS.get(concept, present))
        if set(POOLED_VARIANTS) <= set(required):
            rule = (
                f"p < {alpha:g} in the stratified pooled test and in both standard and "
                "counterbalanced"
            )
            needed = [*POOLED_VARIANTS, POOLED]
        else:
            rule = f"p < {alpha:g} in every variant ({', '.join(required)})"
            needed = required
        untested = [
            variant
            for variant in needed
            if results.get((concept, variant), {}).get("p_value") is None
        ]
        if untested:
            verdicts.append(
                Verdict(
                    concept, None, rule, f"no test of {', '.join(untested)} (needs >= 2 pairs each)"
                )
            )
            continue
        values = {variant: results[(concept, variant)] for variant in needed}
        voe = bool(verdict_rule([values[variant]["p_value"] for variant in needed], alpha))
        failed = []
        for variant in needed:
            p_value, mean = values[variant]["p_value"], values[variant]["relative_surprise"]
            if not mean > 0:
                failed.append(f"{variant} M = {format_number(mean)} <= 0")
            elif not p_value < alpha:
                failed.append(f"{variant} p = {format_p(p_value, alpha)} >= {alpha:g}")
        verdicts.append(Verdict(concept, voe, rule, "" if voe else "; ".join(failed)))
    if causality is not None and not causality.causal:
        return [
            Verdict(v.concept, None, v.rule, causality_check.NOT_CAUSAL, withheld=True)
            for v in verdicts
        ]
    return verdicts
