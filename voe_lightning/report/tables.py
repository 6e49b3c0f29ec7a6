"""The report's statistics rows: the paired test per concept/variant, pooled group and
quadruplet (``summarize``, columns ``SUMMARY_COLUMNS``) and the field's metric set beside it
(``field_metric_rows``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from voe_lightning.report.pairs import PairResults
from voe_lightning.specs import QUADRUPLET_ROWS
from voe_lightning.stats.field_metrics import field_metrics
from voe_lightning.stats.statistics import (
    QuadrupletTestResult,
    group_test,
    untested_reason,
)
from voe_lightning.stats.t_tests import rounding_of

#: Columns of summary.csv, in order (``None`` cells mean "no test", explained in ``note``).
SUMMARY_COLUMNS = ("concept", "variant") + tuple(QuadrupletTestResult.__dataclass_fields__)


def summarize(
    results: PairResults, alpha: float, bootstrap: int = 2000, seed: int = 0
) -> list[dict[str, Any]]:
    """One row per concept/variant, a ``pooled`` row per concept with a counterbalanced
    pair (``statistics.pooled_test``: the stratified test of its variants' mean differences)
    and a row per quadruplet of ``specs.QUADRUPLETS`` (``statistics.quadruplet_test``): the test
    of summed surprise (``statistics.group_test``). A group without a test (fewer than two
    pairs, ``statistics.untested_reason``) gets ``None`` statistics and a note instead of
    failing the report; columns a row's test lacks (the halves of a pair test) are ``None``.
    Every row carries the report's ``alpha``, so its writers read one level from the rows.
    A d within rounding of the per-frame values' precision is 0 (``t_tests.rounding_of``)."""
    rounding = rounding_of(results.surprise_consistent, results.surprise_inconsistent)
    rows = []
    for concept, variant, pairs in results.groups(pooled=True):
        row: dict[str, Any] = dict.fromkeys(SUMMARY_COLUMNS)
        row.update(concept=concept, variant=variant, alpha=alpha)
        reason = untested_reason(variant, pairs.variant)
        if reason:
            row.update(n=len(pairs) // (2 if variant in QUADRUPLET_ROWS else 1), note=reason)
        else:
            row.update(
                group_test(
                    variant,
                    pairs.total_inconsistent,
                    pairs.total_consistent,
                    pairs.variant,
                    alpha=alpha,
                    bootstrap=bootstrap,
                    seed=seed,
                    rounding=rounding,
                ).as_dict()
            )
        rows.append(row)
    return rows


def field_metric_rows(results: PairResults) -> dict[str, dict[str, Any]]:
    """The field's metric set (``field_metrics.field_metrics``: relative accuracy with sum,
    mean and max surprise, absolute accuracy, AUROC) per concept/variant and pooled group, keyed
    ``<concept>/<variant>``; each group's threshold is from its own consistent videos, as
    surprise scales differ between concepts, and the max reads the frames after each pair's
    change. A quadruplet's row is of its quadruplets, as its test is: the per-frame surprise of
    its consistent videos summed (A + B) against its inconsistent ones' (AB + BA), so its n and
    its relative accuracy of the sum are the summary row's. A group with non-finite surprise
    gets a note."""
    rows = {}
    for concept, variant, pairs in results.groups(pooled=True):
        sides = (pairs.surprise_consistent, pairs.surprise_inconsistent)
        first = pairs.first_difference
        assert first is not None  # PairResults fills it in (manipulation_frame + 1)
        if variant in QUADRUPLET_ROWS:  # first halves, then second halves, matched by seed
            half = len(pairs) // 2
            sides = tuple(side[:half] + side[half:] for side in sides)
            first = np.minimum(first[:half], first[half:])
        rows[f"{concept}/{variant}"] = (
            field_metrics(*sides, max_from=np.minimum(first, pairs.num_frames - 1))
            if all(np.isfinite(side).all() for side in sides)
            else {"n_pairs": len(sides[0]), "note": "surprise is not finite: no metrics"}
        )
    return rows
