"""Issue 73, case 3: float32 rounding is no evidence of surprise. A tiny fit's quadruplet row
read t(1) = +inf, p < .001, significant, on D = 1.19e-07, one float32 step of 1.43; a d within
rounding of its pair's surprise now counts as 0 in every test (``t_tests.rounding_as_zero``),
one-shot, streaming and the report's, while a float64 scorer's small d stay real."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from helpers import ALPHA
from scipy import stats

from voe_lightning import specs
from voe_lightning.callbacks import VOEProbeCallback
from voe_lightning.probe_datamodule import ProbeDataModule
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.tables import summarize
from voe_lightning.stats.statistics import paired_test, pooled_test, quadruplet_test
from voe_lightning.stats.streaming_statistics import PairedSurpriseStats

SURPRISE = np.float32(1.43)
ULP = np.nextafter(SURPRISE, np.float32(2)) - SURPRISE  # 1.19e-07


def _float32(values) -> np.ndarray:
    return np.asarray(values, dtype=np.float32)


def test_a_quadruplet_one_float32_step_apart_is_undefined_not_significant():
    one_step = _float32([SURPRISE + ULP] * 2)
    same = _float32([SURPRISE] * 2)
    result = quadruplet_test(one_step, same, same, same, ALPHA, bootstrap=0)
    assert not result.significant and result.p_value == 1.0 and np.isnan(result.t)
    assert result.relative_surprise == 0.0 and "every d = 0" in result.note  # was t = +inf


def test_biased_rounding_over_many_pairs_is_no_difference():
    steps = np.random.default_rng(0).choice([0, 1, 1, 2], size=200)  # mostly one step up
    consistent = _float32(np.full(200, SURPRISE))
    inconsistent = _float32(SURPRISE + steps * ULP)
    assert stats.ttest_rel(inconsistent, consistent, alternative="greater").pvalue < 1e-30
    for result in (
        paired_test(inconsistent, consistent, ALPHA, bootstrap=0),
        pooled_test(inconsistent, consistent, ["standard", "counterbalanced"] * 100, ALPHA, 0),
    ):
        assert not result.significant and result.p_value == 1.0 and result.accuracy == 0.0
    metric = PairedSurpriseStats()  # fit's table, batch by batch
    for batch in range(4):
        rows = slice(50 * batch, 50 * (batch + 1))
        metric.update(torch.from_numpy(inconsistent[rows]), torch.from_numpy(consistent[rows]))
    computed = metric.compute()
    assert float(computed["p_value"]) == 1.0 and torch.isnan(computed["t"])


class _Probes(ProbeDataModule):
    concept_names, variant_names = specs.CONCEPTS, specs.VARIANTS

    def probe_cases(self, split="val"):
        return [("solidity", "standard"), ("solidity", "counterbalanced")]


class _Module:
    device = torch.device("cpu")

    def __init__(self):
        self.logged = {}

    def log(self, name, value, **kwargs):
        self.logged[name] = value


def _fit_table(results: PairResults) -> dict:
    """What fit's VOEProbeCallback logs of these pairs, as one validation batch."""
    trainer = SimpleNamespace(datamodule=_Probes(), sanity_checking=False, global_step=10)
    callback, module = VOEProbeCallback(print_table=False, alpha=ALPHA), _Module()
    callback.on_validation_epoch_start(trainer, module)
    outputs = {
        "concept": torch.tensor([specs.CONCEPTS.index(c) for c in results.concept]),
        "variant": torch.tensor([specs.VARIANTS.index(v) for v in results.variant]),
        "seed": torch.from_numpy(results.seed),
        "manipulation_frame": torch.from_numpy(results.manipulation_frame),
        "surprise_consistent": torch.from_numpy(results.surprise_consistent.astype(np.float32)),
        "surprise_inconsistent": torch.from_numpy(results.surprise_inconsistent.astype(np.float32)),
    }
    callback.on_validation_batch_end(trainer, module, outputs, None, 0)
    callback.on_validation_epoch_end(trainer, module)
    return module.logged


def test_summary_and_fits_table_zero_rounding_of_float32_frames_summed_in_float64():
    """summary.md's rows and fit's table of one set of pairs: per-frame float32 surprise, one
    frame a step apart in every pair (the videos' sums are float64, so only the frames say
    the surprise is float32)."""
    seeds, frames = 4, 6
    rng = np.random.default_rng(1)
    consistent = rng.uniform(0.1, 0.3, (2 * seeds, frames)).astype(np.float32)
    inconsistent = consistent.copy()
    inconsistent[:, 4] = np.nextafter(inconsistent[:, 4], np.float32(1))
    results = PairResults(
        concept=["solidity"] * 2 * seeds,
        variant=["standard"] * seeds + ["counterbalanced"] * seeds,
        seed=list(range(seeds)) * 2,
        manipulation_frame=[2] * 2 * seeds,
        surprise_consistent=consistent,
        surprise_inconsistent=inconsistent,
    )
    rows = summarize(results, ALPHA, bootstrap=0)
    variants = ["standard", "counterbalanced", "pooled", "quadruplet"]
    assert [row["variant"] for row in rows] == variants
    for row in rows:
        assert not row["significant"] and row["p_value"] == 1.0, row  # were t = +inf, p = 0
    logged = _fit_table(results)
    for variant in variants:
        assert logged[f"voe/solidity/{variant}/p_value"] == 1.0, variant
        assert np.isnan(logged[f"voe/solidity/{variant}/t"]), variant


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_a_defined_test_still_agrees_with_scipy(dtype):
    rng = np.random.default_rng(2)
    consistent = rng.normal(50.0, 5.0, 30).astype(dtype)
    inconsistent = (consistent + rng.normal(0.4, 1.0, 30)).astype(dtype)
    result = paired_test(inconsistent, consistent, ALPHA, bootstrap=0)
    expected = stats.ttest_rel(  # in float64, as the test computes
        inconsistent.astype(np.float64), consistent.astype(np.float64), alternative="greater"
    )
    assert result.t == pytest.approx(expected.statistic, rel=1e-9)
    assert result.p_value == pytest.approx(expected.pvalue, rel=1e-9)


def test_a_float64_scorers_small_differences_stay_real():
    """A float64 scorer plus 1e9 (docs/reliability.md): its d are 1e-9 of its surprise, yet
    real; float32 rounding of 1e9 would be 64."""
    rng = np.random.default_rng(3)
    consistent = 1e9 + rng.uniform(0.0, 1.0, 20)
    d = rng.normal(1.0, 1.0, 20)
    result = paired_test(consistent + d, consistent, ALPHA, bootstrap=0)
    expected = stats.ttest_rel(consistent + d, consistent, alternative="greater")
    assert result.t == pytest.approx(expected.statistic, rel=1e-6) and result.significant
