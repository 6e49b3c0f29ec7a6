"""VOEProbeCallback: per concept/variant streaming tests plus the stratified pooled test of a
counterbalanced concept's two variants, logged as voe/<concept>/pooled/*, and the printed
verdict with the run's alpha."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from helpers import ALPHA
from rich.console import Console
from scipy import stats

from voe_lightning import specs
from voe_lightning.callbacks import VOEProbeCallback, VOEReportCallback, voe_table
from voe_lightning.probe_datamodule import ProbeDataModule
from voe_lightning.stats.verdicts import concept_verdicts

CASES = [
    ("object_persistence", "standard"),
    ("object_persistence", "counterbalanced"),
    ("unchangeableness", "color"),
]


class _Probes(ProbeDataModule):
    concept_names, variant_names = specs.CONCEPTS, specs.VARIANTS

    def probe_cases(self, split="val"):
        return CASES


class _Module:
    device = torch.device("cpu")

    def __init__(self):
        self.logged = {}

    def log(self, name, value, **kwargs):
        self.logged[name] = value


def test_probe_callback_logs_the_stratified_pooled_test_of_both_variants():
    rng = np.random.default_rng(0)
    trainer = SimpleNamespace(datamodule=_Probes(), sanity_checking=False, global_step=250)
    callback, module = VOEProbeCallback(print_table=False, alpha=ALPHA), _Module()
    callback.on_validation_epoch_start(trainer, module)
    pairs = {case: ([], []) for case in CASES}
    for batch in range(3):  # mixed batches of all three cases
        index = rng.integers(0, 3, 8)
        consistent = rng.gamma(2.0, 1.0, (8, 5))
        inconsistent = consistent + rng.normal(0.3, 1.0, (8, 5))
        inconsistent[:, :2] = consistent[:, :2]  # causal: identical through the manipulation
        outputs = {
            "concept": torch.tensor([specs.CONCEPTS.index(CASES[i][0]) for i in index]),
            "variant": torch.tensor([specs.VARIANTS.index(CASES[i][1]) for i in index]),
            "manipulation_frame": torch.ones(8, dtype=torch.int64),
            "surprise_consistent": torch.from_numpy(consistent),
            "surprise_inconsistent": torch.from_numpy(inconsistent),
        }
        callback.on_validation_batch_end(trainer, module, outputs, None, batch)
        for row, i in enumerate(index):
            pairs[CASES[i]][0].append(inconsistent[row].sum())
            pairs[CASES[i]][1].append(consistent[row].sum())
    callback.on_validation_epoch_end(trainer, module)

    # Stratified: (M1 + M2) / 2 over 0.5 sqrt(s1^2/n1 + s2^2/n2), which is Welch's t of d1
    # against -d2 (scipy), with its Welch-Satterthwaite df.
    d1, d2 = (np.subtract(*pairs[case]) for case in CASES[:2])
    reference = stats.ttest_ind(d1, -d2, equal_var=False, alternative="greater")
    logged = module.logged
    assert logged["voe/object_persistence/pooled/relative_surprise"] == pytest.approx(
        (d1.mean() + d2.mean()) / 2, rel=1e-12
    )
    assert logged["voe/object_persistence/pooled/t"] == pytest.approx(reference.statistic, rel=1e-9)
    assert logged["voe/object_persistence/pooled/p_value"] == pytest.approx(
        reference.pvalue, rel=1e-9
    )
    assert logged["voe/object_persistence/pooled/accuracy"] == np.mean(np.r_[d1, d2] > 0)
    assert logged["voe/object_persistence/pooled/n"] == d1.size + d2.size
    for statistic in VOEProbeCallback.STATISTICS:
        assert f"voe/object_persistence/pooled/{statistic}" in module.logged
    assert not any(name.startswith("voe/unchangeableness/pooled") for name in module.logged)
    assert list(callback.last) == [CASES[0], CASES[1], ("object_persistence", "pooled"), CASES[2]]
    assert callback.causality.causal and callback.causality.pairs == 24

    console = Console(width=200, record=True)
    console.print(voe_table(callback.last, title="VOE", alpha=0.05))
    text = console.export_text()
    assert "verdict" in text and "pooled" in text
    assert "VOE (α = 0.05)" in text and "* p < 0.05" in text  # the alpha in title and caption
    # unchangeableness has only color's pairs (no seeds: no quadruplet rows): every half untested
    assert (
        "undecided: no test of position, position_counterbalanced, color_counterbalanced," in text
    )


def test_the_table_at_fit_end_names_the_step_its_validation_ran_at(capsys):
    """A fit that ends after its last validation (a cadence in epochs) prints that validation's
    table under the step it ran at, not the step training ended at."""
    rng = np.random.default_rng(2)
    trainer = SimpleNamespace(
        datamodule=_Probes(), sanity_checking=False, global_step=504, is_global_zero=True
    )
    callback, module = VOEProbeCallback(alpha=ALPHA), _Module()
    callback.on_validation_epoch_start(trainer, module)
    consistent = rng.gamma(2.0, 1.0, (8, 5))
    inconsistent = consistent + rng.normal(1.0, 1.0, (8, 5))
    inconsistent[:, :2] = consistent[:, :2]
    outputs = {
        "concept": torch.full((8,), specs.CONCEPTS.index(CASES[0][0])),
        "variant": torch.full((8,), specs.VARIANTS.index(CASES[0][1])),
        "manipulation_frame": torch.ones(8, dtype=torch.int64),
        "surprise_consistent": torch.from_numpy(consistent),
        "surprise_inconsistent": torch.from_numpy(inconsistent),
    }
    callback.on_validation_batch_end(trainer, module, outputs, None, 0)
    callback.on_validation_epoch_end(trainer, module)
    trainer.global_step = 520  # training went on after the last validation
    callback.on_fit_end(trainer, module)
    out = capsys.readouterr().out
    assert "VOE on validation probes, step 504" in out
    assert "step 520" not in out


def test_validate_alone_prints_the_table_and_fit_s_validations_do_not(capsys):
    """``validate`` prints its verdict table when it ends; a validation inside ``fit`` leaves
    the table to fit's end."""
    rng = np.random.default_rng(3)
    callback, module = VOEProbeCallback(alpha=ALPHA), _Module()
    for fn, printed in (("fit", False), ("validate", True)):
        trainer = SimpleNamespace(
            datamodule=_Probes(),
            sanity_checking=False,
            global_step=40,
            is_global_zero=True,
            state=SimpleNamespace(fn=fn),
        )
        callback.on_validation_epoch_start(trainer, module)
        consistent = rng.gamma(2.0, 1.0, (8, 5))
        outputs = {
            "concept": torch.full((8,), specs.CONCEPTS.index(CASES[0][0])),
            "variant": torch.full((8,), specs.VARIANTS.index(CASES[0][1])),
            "manipulation_frame": torch.ones(8, dtype=torch.int64),
            "surprise_consistent": torch.from_numpy(consistent),
            "surprise_inconsistent": torch.from_numpy(consistent + rng.normal(1.0, 1.0, (8, 5))),
        }
        callback.on_validation_batch_end(trainer, module, outputs, None, 0)
        callback.on_validation_epoch_end(trainer, module)
        callback.on_validation_end(trainer, module)
        assert ("VOE on validation probes, step 40" in capsys.readouterr().out) is printed


def test_callbacks_need_the_runs_alpha_and_refuse_a_bad_one():
    assert VOEProbeCallback(alpha=0.05).alpha == VOEReportCallback(alpha=0.05).alpha == 0.05
    for callback in (VOEProbeCallback, VOEReportCallback):
        with pytest.raises(ValueError, match=f"{callback.__name__} was given no alpha"):
            _ = callback().alpha
    with pytest.raises(ValueError, match=r"alpha must be a significance level in \(0, 1\).*got 5"):
        VOEReportCallback(alpha=5)


def test_probe_callback_refuses_a_datamodule_without_names():
    trainer = SimpleNamespace(datamodule=SimpleNamespace(probe_cases=lambda split="val": CASES))
    with pytest.raises(TypeError, match="VOEProbeCallback .* needs a ProbeDataModule"):
        VOEProbeCallback(alpha=ALPHA).on_validation_epoch_start(trainer, _Module())


def test_probe_callback_logs_the_quadruplet_test_the_verdict_reads():
    """Validation probes carry seeds: each seed's standard and counterbalanced pairs are one
    quadruplet, tested over training as the report tests it (scipy's one-sample t of D)."""
    rng = np.random.default_rng(1)
    trainer = SimpleNamespace(datamodule=_Probes(), sanity_checking=False, global_step=250)
    callback, module = VOEProbeCallback(print_table=False, alpha=ALPHA), _Module()
    callback.on_validation_epoch_start(trainer, module)
    quads = 6
    consistent = rng.gamma(2.0, 1.0, (2 * quads, 5))
    inconsistent = consistent + rng.normal(1.0, 1.0, (2 * quads, 5))
    inconsistent[:, :2] = consistent[:, :2]
    order = rng.permutation(2 * quads)  # halves and seeds arrive in any order
    outputs = {
        "concept": torch.full((2 * quads,), specs.CONCEPTS.index("object_persistence"))[order],
        "variant": torch.tensor(
            [specs.VARIANTS.index("standard")] * quads
            + [specs.VARIANTS.index("counterbalanced")] * quads
        )[order],
        "seed": torch.tensor(list(range(quads)) * 2)[order],
        "manipulation_frame": torch.ones(2 * quads, dtype=torch.int64),
        "surprise_consistent": torch.from_numpy(consistent[order]),
        "surprise_inconsistent": torch.from_numpy(inconsistent[order]),
    }
    callback.on_validation_batch_end(trainer, module, outputs, None, 0)
    callback.on_validation_epoch_end(trainer, module)
    d = inconsistent.sum(1) - consistent.sum(1)
    quadruplet = d[:quads] + d[quads:]
    reference = stats.ttest_1samp(quadruplet, 0, alternative="greater")
    logged = module.logged
    assert logged["voe/object_persistence/quadruplet/t"] == pytest.approx(reference.statistic)
    assert logged["voe/object_persistence/quadruplet/p_value"] == pytest.approx(reference.pvalue)
    assert logged["voe/object_persistence/quadruplet/n"] == quads
    assert logged["voe/object_persistence/quadruplet/first_half"] == pytest.approx(d[:quads].mean())
    assert logged["voe/object_persistence/quadruplet/second_half"] == pytest.approx(
        d[quads:].mean()
    )
    assert list(callback.last)[-1] == ("object_persistence", "quadruplet")
    verdict = {v.concept: v for v in concept_verdicts(callback.last, alpha=ALPHA)}[
        "object_persistence"
    ]
    assert "quadruplet test" in verdict.rule
