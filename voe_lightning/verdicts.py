"""Which rows a VOE table has and the verdict they give (docs/architecture.md §8): every
concept/variant among the probe pairs, plus a ``pooled`` row for a concept with a standard and
a counterbalanced variant (``pair_groups``); and per concept, whether it shows VOE
(``concept_verdicts``: every test its verdict reads significant at alpha, ``verdict_rule``).
The tests themselves are in ``voe_lightning.statistics``; the verdict's calibration in
``voe_lightning.calibration``."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from voe_lightning import specs
from voe_lightning.causality import NOT_CAUSAL, Causality
from voe_lightning.statistics import ALPHA, POOLED, POOLED_VARIANTS, check_alpha
from voe_lightning.statistics_format import format_number, format_p

__all__ = ["Verdict", "concept_verdicts", "pair_groups", "verdict_rule"]


def pair_groups(
    concepts: Sequence[str], variants: Sequence[str], pooled: bool = True
) -> list[tuple[str, str, np.ndarray]]:
    """(concept, variant, boolean row selector) for every concept/variant among the pairs, in
    ``specs`` order where known (others after, in order of first appearance). With ``pooled``,
    a concept holding both ``standard`` and ``counterbalanced`` pairs gets a ``pooled`` group
    (the pairs of both, tested by ``pooled_test``) right after its variants."""
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


def concept_verdicts(
    results: Mapping[tuple[str, str], Mapping[str, Any]] | Sequence[Mapping[str, Any]],
    alpha: float = ALPHA,
    causality: Causality | None = None,
) -> list[Verdict]:
    """Per concept, in the order first seen, ``verdict_rule`` over the tests it reads: for a
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
        present = [v for c, v in results if c == concept and v != POOLED]
        required = list(specs.STANDARD_VARIANTS.get(concept, present))
        if set(POOLED_VARIANTS) <= set(required):
            rule = (f"p < {alpha:g} in the stratified pooled test and in both standard and "
                    "counterbalanced")
            needed = [*POOLED_VARIANTS, POOLED]
        else:
            rule = f"p < {alpha:g} in every variant ({', '.join(required)})"
            needed = required
        if causality is not None and not causality.causal:
            verdicts.append(Verdict(concept, None, rule, NOT_CAUSAL, withheld=True))
            continue
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
    return verdicts
