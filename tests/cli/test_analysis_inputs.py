"""Issue 73: what ``analyze`` reads. A later ``validate`` is no step 0 of a training curve
(case 5); ``analyze null --trained`` places a t only among t's on the same probes (case 7); a
significance level outside (0, 1) and two runs drawing one curve under one label are refused."""

import json

import numpy as np
import pytest
from helpers import refused
from helpers.locations import TINY_CONFIG
from helpers.runs import write_events
from torch.utils.tensorboard import SummaryWriter

from voe_lightning.analysis import training_curves
from voe_lightning.analysis.emergence import first_voe_step, read_quadruplet_curves
from voe_lightning.analysis.null import check_same_probes
from voe_lightning.cli import main

STEPS = range(100, 600, 100)
QUADRUPLET = "voe/continuity/quadruplet"
#: The step-0 scalars ``validate --ckpt_path last`` logs into a run: the trained model's values.
TRAINED = {"hp_metric": -1.0, "val/kl": 1.4, "epoch": 0.0}


def _validate_into(folder, scalars):
    """An event file as a later ``validate`` writes it: no training scalar, all at step 0."""
    writer = SummaryWriter(str(folder))
    for tag, value in {**TRAINED, **scalars}.items():
        writer.add_scalar(tag, value, 0)
    writer.close()


def _fit_with_voe_from(run, first):
    """A fit's event file whose continuity quadruplet shows VOE at every validation from
    step ``first`` (250 apart, to 1250)."""
    writer = SummaryWriter(str(run))
    for step in range(first, 1500, 250):
        writer.add_scalar("train/loss", 1.0 / step, step)
        for name, value in (("t", 5.0), ("p_value", 1e-4), ("n", 24), ("first_half", 1.0)):
            writer.add_scalar(f"{QUADRUPLET}/{name}", value, step)
        writer.add_scalar(f"{QUADRUPLET}/second_half", 1.0, step)
    writer.close()


# ------------------------------------------------------------------ 5: a later validate
def test_a_later_validate_is_no_step_0_of_the_curve(tmp_path):
    run = tmp_path / "version_0"
    write_events(run, {("solidity", "standard"): lambda s: s / 100.0}, steps=STEPS)
    tag = "voe/solidity/standard/relative_surprise"
    _validate_into(run, {tag: 4.0})  # validate --ckpt_path last: into the run itself
    _validate_into(run / "data_other-0123abcd", {tag: -7.0})  # on other data: a sub-folder
    [(steps, values)] = training_curves.read_relative_surprise(run).values()
    np.testing.assert_array_equal(steps, list(STEPS))  # was [0, 100, ...]: the trained 4.0 first
    np.testing.assert_allclose(values, [1, 2, 3, 4, 5])
    figure = training_curves.relative_surprise_curves_figure([("joint", run)])
    [line] = figure.axes[0].get_lines()[:1]
    assert line.get_xdata()[0] == 100


def test_a_later_validate_does_not_move_where_voe_emerges(tmp_path):
    run = tmp_path / "version_0"
    _fit_with_voe_from(run, 250)
    trained = {"t": 6.0, "p_value": 1e-5, "n": 24, "first_half": 1.0, "second_half": 1.0}
    _validate_into(run, {f"{QUADRUPLET}/{name}": value for name, value in trained.items()})
    curves = read_quadruplet_curves(run)[("continuity", "quadruplet")]
    assert curves["t"][0][0] == 250
    assert first_voe_step(curves, 0.01) == 250  # was 0: "VOE from step 0"


# -------------------------------------------------------- 7: null --trained on other probes
def _summary(n=3, **source):
    rows = [{"concept": "object_persistence", "variant": "standard", "t": 2.0, "n": n}]
    return {"alpha": 0.01, "source": source, "rows": rows, "verdicts": []}


def test_a_trained_report_on_other_probes_or_n_is_refused():
    null = _summary(data_root="data/tiny", seed_offset=0, probe_split="test")
    check_same_probes(null, _summary(data_root="data/./tiny", seed_offset=0), "r")  # the same
    check_same_probes(null, {**_summary(), "source": {}}, "r")  # an older report: n alone
    with pytest.raises(ValueError, match="its seed_offset is 6000000, theirs 0"):
        check_same_probes(null, _summary(data_root="data/tiny", seed_offset=6000000), "r")
    with pytest.raises(ValueError, match=r"object_persistence/standard has n = 200, theirs n = 3"):
        check_same_probes(null, _summary(n=200, data_root="data/tiny", seed_offset=0), "r")


def test_analyze_null_refuses_a_trained_report_on_fresh_probes(workdir, capsys):
    """The untrained initializations are tested on data/tiny's test probes; the trained
    report on a fresh set (seed offset 6000000, 200 pairs): no percentile of it is printed."""
    report = workdir / "trained" / "voe_report"
    report.mkdir(parents=True)
    trained = _summary(
        n=200, data_root="data/tiny", seed_offset=6000000, probe_split="test", probe_root="x"
    )
    (report / "summary.json").write_text(json.dumps(trained))
    error = refused(
        capsys,
        ["analyze", "null", "--configs", f"[{TINY_CONFIG}]", "--seeds", "2"]
        + ["--out", "untrained", "--trained", str(report)]
        + ["--extra_args", '["--trainer.enable_progress_bar", "false"]'],
    )
    assert f"--trained {report} was tested on other probes" in error
    assert "its seed_offset is 6000000, theirs 0" in error
    assert not (workdir / "untrained" / "null.md").exists()
    assert not (workdir / "untrained" / "seed_1").exists()  # refused after the first initialization


# ---------------------------------------------------------------------- smaller ones
def test_emergence_refuses_an_alpha_outside_0_1(tmp_path, capsys):
    _fit_with_voe_from(tmp_path / "run", 250)
    out = tmp_path / "e.png"
    error = refused(
        capsys,
        ["analyze", "emergence", "--runs", f"[{tmp_path / 'run'}]", "--out", str(out)]
        + ["--alpha", "5"],
    )  # was drawn, every t "significant" at alpha = 5
    assert "alpha must be a significance level in (0, 1)" in error and "got 5" in error
    assert not out.exists()


def test_curves_refuse_two_runs_drawing_one_curve_under_one_label(tmp_path, capsys):
    for name in ("a", "b"):
        write_events(tmp_path / name, {("solidity", "standard"): lambda s: s / 100.0})
    write_events(tmp_path / "c", {("continuity", "standard"): lambda s: 0.0})
    out = tmp_path / "curves.png"
    main(
        ["analyze", "curves", "--runs", f"[x={tmp_path / 'a'}, x={tmp_path / 'c'}]"]
        + ["--out", str(out)]
    )  # different concepts may share a label (the separate runs)
    assert out.stat().st_size > 0
    error = refused(
        capsys,
        ["analyze", "curves", "--runs", f"[x={tmp_path / 'a'}, x={tmp_path / 'b'}]"]
        + ["--out", str(tmp_path / "two.png")],
    )
    assert "are both labelled 'x' and both have solidity/standard curves" in error
    assert not (tmp_path / "two.png").exists()
