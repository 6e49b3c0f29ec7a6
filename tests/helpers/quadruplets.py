"""The check that a benchmark's probe records expose their quadruplets as our stores do (a seed
names a quadruplet, the variant its half), so a report tests them by the quadruplet test
(the benchmark reader tests' shared check)."""

import numpy as np
import pytest

from helpers import ALPHA
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.tables import summarize
from voe_lightning.specs import QUADRUPLET
from voe_lightning.stats.statistics import quadruplet_test
from voe_lightning.stats.verdicts import concept_verdicts


def check_quadruplet_rows(probes, concept_names, variant_names, quadruplets: dict[str, int]):
    """Summarize ``probes`` (a batch of probe records) with surprise that rises in every
    inconsistent video; each concept of ``quadruplets`` must get a quadruplet row over that
    many quadruplets, the test of ``statistics.quadruplet_test`` on its standard and
    counterbalanced pairs matched by seed (none of one quadruplet), and a verdict read from it
    (VOE; undecided without a test)."""
    rng = np.random.default_rng(0)
    frames = probes["manipulation_frame"].shape[0], probes["consistent", "frames"].shape[1]
    consistent = rng.normal(2.0, 0.1, frames)
    inconsistent = consistent + rng.uniform(0.5, 1.5, frames)
    results = PairResults.from_probe_outputs(
        [
            {
                "concept": probes["concept"],
                "variant": probes["variant"],
                "seed": probes["seed"],
                "manipulation_frame": probes["manipulation_frame"],
                "surprise_consistent": consistent,
                "surprise_inconsistent": inconsistent,
            }
        ],
        concept_names,
        variant_names,
    )
    rows = {
        (row["concept"], row["variant"]): row
        for row in summarize(results, bootstrap=0, alpha=ALPHA)
    }
    concepts, variants = np.array(results.concept), np.array(results.variant)
    for concept, count in quadruplets.items():
        row = rows[(concept, QUADRUPLET)]
        assert row["n"] == count
        if count < 2:  # one quadruplet: a row without a test
            assert row["p_value"] is None
            continue
        halves = [
            np.flatnonzero((concepts == concept) & (variants == variant))
            for variant in ("standard", "counterbalanced")
        ]
        halves = [half[np.argsort(results.seed[half])] for half in halves]
        assert results.seed[halves[0]].tolist() == results.seed[halves[1]].tolist()
        inc, con = results.total_inconsistent, results.total_consistent
        expected = quadruplet_test(
            inc[halves[0]], con[halves[0]], inc[halves[1]], con[halves[1]], bootstrap=0, alpha=ALPHA
        )
        assert row["relative_surprise"] == pytest.approx(expected.relative_surprise)
        assert row["p_value"] == pytest.approx(expected.p_value)
    verdicts = {v.concept: v for v in concept_verdicts(list(rows.values()), alpha=ALPHA)}
    for concept, count in quadruplets.items():
        assert "quadruplet test" in verdicts[concept].rule
        assert verdicts[concept].voe == (True if count >= 2 else None)
