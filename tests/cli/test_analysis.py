"""Analyses over runs: curves from real TensorBoard event files, the size sweep (statistics,
plot, and the driver's orchestration with a stand-in CLI), the ``analyze`` command line, and
the report notebook executed on a tiny synthetic run directory."""

import json
import os
import types
from pathlib import Path

import nbformat
import numpy as np
import pytest
from helpers import ALPHA
from helpers.locations import REPO
from helpers.runs import curve_runs, write_events
from nbclient import NotebookClient
from PIL import Image

from voe_lightning import specs
from voe_lightning.analysis import comparison, size_sweep, training_curves
from voe_lightning.callbacks import VOEReportCallback
from voe_lightning.cli import main
from voe_lightning.report import ReportInputs, write_report
from voe_lightning.report.pairs import PairResults
from voe_lightning.runs import trained_reports
from voe_lightning.stats.statistics import paired_test

NOTEBOOK = REPO / "notebooks" / "voe_report.ipynb"
T = 5


def pair_results(groups, seed=0):
    """n pairs per (concept, variant) with relative surprise ~ N(effect, 1) at one frame, the
    one after the manipulation frame (causal: identical through it)."""
    rng = np.random.default_rng(seed)
    rows = []
    for (concept, variant), (n, effect) in groups.items():
        for i in range(n):
            consistent = rng.gamma(2.0, 1.0, T)
            inconsistent = consistent.copy()
            inconsistent[2] += rng.normal(effect, 1.0)
            rows.append((concept, variant, 1000 - i, 1, consistent, inconsistent))
    return PairResults(*map(list, zip(*rows)))


def test_read_scalars_filters_tags_and_merges_resumed_runs(tmp_path):
    write_events(tmp_path / "version_0", {("solidity", "standard"): lambda s: s / 100.0})
    # A resumed run writes more events (one repeated step) into a second file of the same run.
    write_events(
        tmp_path / "version_0", {("solidity", "standard"): lambda s: -1.0}, steps=[400, 500]
    )
    scalars = training_curves.read_scalars(tmp_path)
    assert list(scalars) == ["voe/solidity/standard/relative_surprise"]
    steps, values = scalars["voe/solidity/standard/relative_surprise"]
    np.testing.assert_array_equal(steps, [0, 100, 200, 300, 400, 500])
    np.testing.assert_allclose(values, [0, 1, 2, 3, -1, -1])
    loss = training_curves.read_scalars(tmp_path, r"^train/loss$")["train/loss"]
    assert loss[1][0] == pytest.approx(1.0)
    curves = training_curves.read_relative_surprise(tmp_path)
    assert list(curves) == [("solidity", "standard")]


def test_missing_runs_and_tags_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        training_curves.read_scalars(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match="no TensorBoard event files"):
        training_curves.read_scalars(tmp_path)
    write_events(tmp_path / "run", {}, other_tags=True)
    with pytest.raises(ValueError, match="has no voe/<concept>/<variant>/relative_surprise"):
        training_curves.relative_surprise_curves_figure([("joint", tmp_path / "run")])
    write_events(tmp_path / "ok", {("solidity", "standard"): lambda s: 1.0})
    with pytest.raises(ValueError, match="unknown run labels"):
        training_curves.relative_surprise_curves_figure(
            [("joint", tmp_path / "ok")], {"separate": 0.5}
        )


def test_curves_figure_draws_every_run_and_variant(tmp_path):
    runs = curve_runs(tmp_path)
    figure = training_curves.relative_surprise_curves_figure(runs, {"joint": 0.2})
    visible = [ax for ax in figure.axes if ax.get_visible()]
    assert [ax.get_title() for ax in visible] == ["object_persistence", "unchangeableness"]
    lines = {
        line.get_label(): line
        for line in visible[0].get_lines()
        if not line.get_label().startswith("_")
    }
    assert set(lines) == {
        "standard (joint)",
        "standard (separate)",
        "counterbalanced (joint)",
        "counterbalanced (separate)",
    }
    assert lines["standard (joint)"].get_linestyle() == "-"
    assert lines["standard (separate)"].get_linestyle() == "--"
    np.testing.assert_allclose(lines["standard (joint)"].get_xdata(), np.arange(0, 500, 100) * 0.2)
    assert lines["standard (joint)"].get_color() == lines["standard (separate)"].get_color()


def test_curves_of_three_runs_are_told_apart_by_style_and_marker(tmp_path):
    """Three runs not named joint/separate (e.g. three model families) each get a line style
    and a marker of their own, named in the title (the third once reused the first's)."""
    labels = ["VRNN-LRU", "object-centric", "object-free"]
    for index, label in enumerate(labels):
        write_events(
            tmp_path / label, {("solidity", "standard"): (lambda s, a=index: a + np.log1p(s / 50))}
        )
    figure = training_curves.relative_surprise_curves_figure(
        [(label, tmp_path / label) for label in labels]
    )
    lines = [line for line in figure.axes[0].get_lines() if not line.get_label().startswith("_")]
    styles = {(str(line.get_linestyle()), line.get_marker()) for line in lines}
    assert len(lines) == 3 and len(styles) == 3
    assert len({line.get_linestyle() for line in lines}) == 3
    title = figure._suptitle.get_text()
    assert "VRNN-LRU: solid, circles" in title and "object-free: dotted, triangles" in title


def test_sweep_rows_are_disjoint_evaluation_sets(tmp_path):
    results = pair_results(
        {("object_persistence", "standard"): (30, 1.0), ("continuity", "standard"): (31, 0.0)}
    )
    rows = size_sweep.sweep_rows(results, train_size=100, eval_sets=3, alpha=ALPHA)
    assert len(rows) == 6 and {r["train_size"] for r in rows} == {100}
    persistence = [r for r in rows if r["concept"] == "object_persistence"]
    assert [r["eval_set"] for r in persistence] == [0, 1, 2]
    assert [r["n"] for r in persistence] == [10] * 3
    assert sum(r["n"] for r in rows if r["concept"] == "continuity") == 31
    (_, _, pairs), _ = results.groups()
    first = pairs.select(np.argsort(pairs.seed)[:10])  # the 10 lowest seeds form set 0
    expected = paired_test(
        first.total_inconsistent, first.total_consistent, bootstrap=0, alpha=ALPHA
    )
    assert persistence[0]["t"] == expected.t and persistence[0]["p_value"] == expected.p_value
    with pytest.raises(ValueError, match="too few for 20 evaluation sets"):
        size_sweep.sweep_rows(results, 100, eval_sets=20, alpha=ALPHA)


def test_size_sweep_figure_marks_significant_points_green():
    rows = [
        {
            "train_size": size,
            "eval_set": i,
            "concept": "object_persistence",
            "variant": "standard",
            "relative_surprise": effect,
            "significant": effect > 0.5,
            "alpha": 0.01,
        }
        for size, effect in ((100, 0.1), (1000, 0.6), (10000, 0.9))
        for i in range(2)
    ]
    figure = size_sweep.size_sweep_figure(rows)
    ax = figure.axes[0]
    assert ax.get_xscale() == "log"
    colors = {points.get_label(): points.get_facecolor()[0][:3] for points in ax.collections}
    tab_green = (0.172, 0.627, 0.172)
    assert np.allclose(colors["significant (p < 0.01)"], tab_green, atol=0.01)  # the rows' alpha
    assert len(ax.collections[0].get_offsets()) == 4
    older = size_sweep.size_sweep_figure(
        [{k: v for k, v in r.items() if k != "alpha"} for r in rows]
    )
    assert "significant" in {points.get_label() for points in older.axes[0].collections}


def test_run_size_sweep_drives_fit_then_test(tmp_path):
    calls = []

    def fake_cli(args):
        """Stands in for voe_lightning.cli.main: 'fit' returns a checkpoint, 'test' a report."""
        calls.append(args)
        size = int(args[args.index("--data.train_examples") + 1])
        checkpoint = types.SimpleNamespace(last_model_path=f"/ckpt/{size}.ckpt", best_model_path="")
        callback = VOEReportCallback(alpha=ALPHA)
        if args[0] == "test":
            pairs = int(args[args.index("--data.test_pairs") + 1])
            write_report(
                ReportInputs(
                    pair_results({("solidity", "standard"): (pairs, size / 100)}, seed=size),
                    bootstrap=0,
                    alpha=0.05,
                ),
                tmp_path / f"test_{size}",
                echo=False,
            )
            callback.report_dir = tmp_path / f"test_{size}" / "voe_report"
        return types.SimpleNamespace(
            trainer=types.SimpleNamespace(checkpoint_callback=checkpoint, callbacks=[callback])
        )

    out = tmp_path / "sweep" / "sweep.json"
    rows = size_sweep.run_size_sweep(
        ["configs/base.yaml", "configs/x.yaml"],
        [10, 300],
        eval_sets=2,
        pairs_per_set=6,
        out=out,
        extra_args=["--data.root=data/sweep_{size}"],
        test_args=["--data.generalization=true"],
        cli_main=fake_cli,
    )
    # fit generates the store, so it must ask for the same number of test pairs as test
    assert calls[0] == [
        "fit",
        "--config",
        "configs/base.yaml",
        "--config",
        "configs/x.yaml",
        "--data.train_examples",
        "10",
        "--data.test_pairs",
        "12",
        "--data.root=data/sweep_10",
    ]
    assert calls[1] == [
        "test",
        "--config",
        "configs/base.yaml",
        "--config",
        "configs/x.yaml",
        "--data.train_examples",
        "10",
        "--data.test_pairs",
        "12",
        "--data.root=data/sweep_10",
        "--ckpt_path",
        "/ckpt/10.ckpt",
        "--data.generalization=true",
    ]
    assert calls[3][0] == "test" and "--data.root=data/sweep_300" in calls[3]
    assert [(r["train_size"], r["eval_set"], r["n"]) for r in rows] == [
        (10, 0, 6),
        (10, 1, 6),
        (300, 0, 6),
        (300, 1, 6),
    ]
    assert json.loads(out.read_text()) == rows
    assert {r["alpha"] for r in rows} == {0.05}  # each evaluation set at its run's alpha


def test_run_size_sweep_names_a_missing_report_callback(tmp_path):
    def no_report(args):
        checkpoint = types.SimpleNamespace(last_model_path="/ckpt/x.ckpt", best_model_path="")
        return types.SimpleNamespace(
            trainer=types.SimpleNamespace(checkpoint_callback=checkpoint, callbacks=[])
        )

    with pytest.raises(RuntimeError, match="add voe_lightning.callbacks.VOEReportCallback"):
        size_sweep.run_size_sweep(["c.yaml"], [5], out=tmp_path / "s.json", cli_main=no_report)


def test_sweep_command_runs_fit_and_test_through_the_cli_main(monkeypatch, tmp_path):
    """``analyze sweep`` gets the CLI's entry point from the CLI (size_sweep imports no CLI)."""
    received = {}
    monkeypatch.setattr(
        size_sweep,
        "run_size_sweep",
        lambda *args, cli_main: received.update(args=args, cli_main=cli_main) or [],
    )
    main(
        [
            "analyze",
            "sweep",
            "--lightning_configs",
            "[configs/quickstart.yaml]",
            "--sizes",
            "[5]",
            "--out",
            str(tmp_path / "sweep.json"),
        ]
    )
    assert received["cli_main"] is main and received["args"][1] == [5]
    with pytest.raises(TypeError, match="run it as `python -m voe_lightning analyze sweep`"):
        size_sweep.sweep([Path("configs/quickstart.yaml")], [5])


def test_command_line_writes_the_figures(tmp_path, capsys):
    runs = curve_runs(tmp_path)
    curves_png = tmp_path / "figs" / "curves.png"
    main(
        [
            "analyze",
            "curves",
            "--runs",
            json.dumps([f"{label}={path}" for label, path in runs]),
            "--step_scale",
            "{joint: 0.2}",
            "--out",
            str(curves_png),
        ]
    )
    for size, effect in ((100, 0.1), (1000, 1.0)):
        write_report(
            ReportInputs(
                pair_results({("solidity", "standard"): (40, effect)}, seed=size),
                alpha=ALPHA,
                bootstrap=0,
            ),
            tmp_path / f"run_{size}" / "version_0",
            echo=False,
        )
    sweep_png = tmp_path / "figs" / "sweep.png"
    main(
        [
            "analyze",
            "sweep-plot",
            "--runs.100",
            str(tmp_path / "run_100"),
            "--runs.1000",
            str(tmp_path / "run_1000"),
            "--eval_sets",
            "4",
            "--out",
            str(sweep_png),
        ]
    )
    rows = [
        {
            "train_size": 10,
            "eval_set": 0,
            "concept": "c",
            "variant": "v",
            "relative_surprise": 1.0,
            "significant": True,
        }
    ]
    (tmp_path / "sweep.json").write_text(json.dumps(rows))
    main(
        [
            "analyze",
            "sweep-plot",
            "--results",
            str(tmp_path / "sweep.json"),
            "--out",
            str(tmp_path / "s2.png"),
        ]
    )
    for path in (curves_png, sweep_png, tmp_path / "s2.png"):
        with Image.open(path) as image:
            assert image.format == "PNG" and image.size[0] > 400
    assert "wrote" in capsys.readouterr().out
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["analyze", "curves", "--runs", "[x]"])
    assert "required: analyze.curves.out" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["analyze", "sweep-plot", "--out", str(tmp_path / "s3.png")])
    assert "either results" in capsys.readouterr().err


@pytest.mark.slow
def test_notebook_reproduces_the_figures_of_a_run_directory(tmp_path, monkeypatch):
    run = tmp_path / "lightning_logs" / "version_0"
    paired = pair_results(
        {("object_persistence", "standard"): (12, 1.0), ("continuity", "standard"): (12, 0.0)}
    )
    write_report(ReportInputs(paired, alpha=ALPHA, bootstrap=100), run, echo=False)
    write_events(
        run,
        {
            ("object_persistence", "standard"): lambda s: s / 400,
            ("continuity", "standard"): lambda s: 0.0,
        },
    )
    sweep = size_sweep.sweep_rows(paired, 100, 2, alpha=ALPHA)
    (tmp_path / "sweep.json").write_text(json.dumps(sweep))
    monkeypatch.setenv("VOE_RUN_DIR", str(tmp_path))
    monkeypatch.setenv("VOE_SWEEP_RESULTS", str(tmp_path / "sweep.json"))
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(
        notebook,
        timeout=120,
        kernel_name="python3",
        resources={"metadata": {"path": str(tmp_path)}},
    ).execute()
    outputs = [
        output for cell in notebook.cells if cell.cell_type == "code" for output in cell.outputs
    ]
    images = [output for output in outputs if "image/png" in output.get("data", {})]
    assert len(images) >= 4  # histograms, per-frame, curves, sweep
    text = "".join(output.get("text", "") for output in outputs)
    assert "24 probe pairs of 5 frames" in text
    markdown = "".join(output.get("data", {}).get("text/markdown", "") for output in outputs)
    assert "| object_persistence | standard | 12 |" in markdown


def test_compare_reads_each_verdicts_rows_beside_the_cue_audit(tmp_path, capsys):
    """`analyze compare`: a quadruplet concept contributes its quadruplet rows (the pairs'
    seeds match the halves), unchangeableness one per change (never the generalization
    variants); effects and verdicts match the reports."""
    groups = {
        ("solidity", "standard"): (40, 2.0),
        ("solidity", "counterbalanced"): (40, 2.0),
        **{("unchangeableness", v): (30, 0.0) for v in specs.VERDICT_VARIANTS["unchangeableness"]},
        ("unchangeableness", "shape_plus1"): (30, 3.0),
    }
    write_report(
        ReportInputs(pair_results(groups, seed=1), alpha=ALPHA, bootstrap=0),
        tmp_path / "a",
        echo=False,
    )
    write_report(
        ReportInputs(
            pair_results(
                {("solidity", "standard"): (40, 2.0), ("solidity", "counterbalanced"): (40, -2.0)},
                seed=2,
            ),
            alpha=ALPHA,
            bootstrap=0,
        ),
        tmp_path / "b",
        echo=False,
    )
    rows = comparison.comparison_rows([("a", tmp_path / "a"), ("b", tmp_path / "b")])
    assert [(r["run"], r["concept"], r["variant"], r["n"]) for r in rows] == [
        ("a", "unchangeableness", "position_quadruplet", 30),
        ("a", "unchangeableness", "color_quadruplet", 30),
        ("a", "unchangeableness", "shape_quadruplet", 30),
        ("a", "solidity", "quadruplet", 40),
        ("b", "solidity", "quadruplet", 40),
    ]
    solidity_a, solidity_b = rows[3], rows[4]
    assert solidity_a["voe"] is True and solidity_b["voe"] is False  # b: a half's M < 0
    assert solidity_a["p_value"] < 1e-6 and solidity_a["cue_accuracy_min"] is None  # no audit
    assert solidity_a["tracked_cue_r"] is None

    out = tmp_path / "compare.md"
    main(
        [
            "analyze",
            "compare",
            "--runs+",
            f"a={tmp_path / 'a'}",
            "--runs+",
            f"b={tmp_path / 'b'}",
            "--out",
            str(out),
        ]
    )
    table = out.read_text()
    assert table == capsys.readouterr().out
    assert "| a | solidity | quadruplet | 40 |" in table and table.count("**yes**") == 1
    t = np.array([solidity_a["t"], solidity_b["t"]])
    first = np.array([solidity_a["first_half"], solidity_b["first_half"]])
    second = np.array([solidity_a["second_half"], solidity_b["second_half"]])
    assert "Over the 2 runs (mean ± sd; sd with n − 1):" in table
    assert (
        f"| solidity | quadruplet | 2 | {t.mean():.2f} ± {t.std(ddof=1):.2f} | "
        f"{first.mean():.2f} ± {first.std(ddof=1):.2f} / "
        f"{second.mean():.2f} ± {second.std(ddof=1):.2f} | 1 of 2 |"
    ) in table
    assert "| unchangeableness | shape_quadruplet | 1 |" in table  # only a has it
    with pytest.raises(FileNotFoundError, match="run test first"):
        comparison.comparison_rows([("missing", tmp_path / "missing")])


def test_compare_reads_a_runs_own_report_before_a_newer_one_on_other_data(tmp_path):
    """`test` writes reports of external benchmarks or other data into sub-folders of the
    run; `analyze compare` of the run reads the run's own report, even when older."""
    run = tmp_path / "run"
    write_report(
        ReportInputs(
            pair_results(
                {("solidity", "standard"): (40, 2.0), ("solidity", "counterbalanced"): (40, 2.0)},
                seed=1,
            ),
            alpha=ALPHA,
            bootstrap=0,
        ),
        run,
        echo=False,
    )
    (run / "config.yaml").write_text("data: {init_args: {root: data/x}}\n")
    write_report(
        ReportInputs(
            pair_results(
                {("solidity", "standard"): (12, 2.0), ("solidity", "counterbalanced"): (12, 2.0)},
                seed=2,
            ),
            alpha=ALPHA,
            bootstrap=0,
        ),
        run / "data_data_tpyo",
        echo=False,
    )
    rows = comparison.comparison_rows([("run", run)])
    assert [(r["variant"], r["n"]) for r in rows] == [("quadruplet", 40)]
    assert rows[0]["report"] == str(run / "voe_report")


def test_compare_and_sweep_plot_never_read_an_untrained_copys_report(tmp_path):
    """A test with ``priors_alone`` writes the untrained copy's report first, in its own run
    folder (with a config.yaml beside it) under the test's folder: `analyze compare` and
    `sweep-plot` read the trained model's report, not that one."""
    evaluation = tmp_path / "run" / "version_0" / "data_fresh-1234"
    untrained = evaluation / "priors_alone" / "seed_0" / "version_0"
    groups = {("solidity", "standard"): (40, 0.0), ("solidity", "counterbalanced"): (40, 0.0)}
    write_report(ReportInputs(pair_results(groups, seed=1), alpha=ALPHA, bootstrap=0), untrained, echo=False)  # fmt: skip
    (untrained / "config.yaml").write_text("model: {}\n")
    trained = {("solidity", "standard"): (40, 2.0), ("solidity", "counterbalanced"): (40, 2.0)}
    write_report(ReportInputs(pair_results(trained, seed=2), alpha=ALPHA, bootstrap=0), evaluation, echo=False)  # fmt: skip
    assert comparison._latest_report(tmp_path / "run") == evaluation / "voe_report"
    os.utime(untrained / "voe_report" / "pairs.csv")  # newest, and still not read
    assert trained_reports(tmp_path / "run", "pairs.csv") == [
        evaluation / "voe_report" / "pairs.csv"
    ]
