"""The field's metric set (voe_lightning.stats.field_metrics) against hand computations and
scikit-learn, and where it is written: our probe report's summary.json and summary.md, and the
quadruplet benchmarks' metrics."""

import json

import numpy as np
import pytest
from helpers import ALPHA

from voe_lightning.benchmarks.metrics import quadruplet_metrics
from voe_lightning.cli import main
from voe_lightning.report import PairResults, ReportInputs, write_report
from voe_lightning.stats.field_metrics import (
    REDUCTIONS,
    context_sweep,
    field_metrics,
    format_field_metrics,
    reduce_surprise,
)

# Four pairs of three frames (possible, impossible), chosen so the reductions disagree.
POSSIBLE = [[0, 1, 0], [2, 2, 2], [1, 1, 1], [0, 0, 5]]
IMPOSSIBLE = [[0, 0, 3], [0, 0, 4], [1, 1, 1], [1, 1, 1]]


def test_the_metric_set_matches_a_hand_computation():
    metrics = field_metrics(POSSIBLE, IMPOSSIBLE)
    # sums: possible 1, 6, 3, 5 vs impossible 3, 4, 3, 3 -> right, wrong, tie, wrong
    assert metrics["relative_accuracy_sum"] == pytest.approx(1.5 / 4)
    assert metrics["relative_accuracy_mean"] == pytest.approx(1.5 / 4)  # same order as sums
    # maxima: possible 1, 2, 1, 5 vs impossible 3, 4, 1, 1 -> right, right, tie, wrong
    assert metrics["relative_accuracy_max"] == pytest.approx(2.5 / 4)
    assert metrics["ties_sum"] == metrics["ties_mean"] == metrics["ties_max"] == 1
    # threshold: 90th percentile of possible maxima {1, 1, 2, 5}: index 2.7 -> 2 + 0.7 * 3
    assert metrics["threshold"] == pytest.approx(4.1)
    # possible called right: 1, 2, 1 (<= 4.1), not 5; impossible called right: none > 4.1
    assert metrics["absolute_accuracy"] == pytest.approx(3 / 8)
    # impossible maxima {3, 4, 1, 1} over possible {1, 2, 1, 5}: wins + ties / 2 of 16
    assert metrics["auroc_max"] == pytest.approx((3 + 3 + 1 + 1) / 16)
    assert metrics["n_pairs"] == 4
    given = field_metrics(POSSIBLE, IMPOSSIBLE, threshold=0.5)
    assert given["threshold"] == 0.5 and given["absolute_accuracy"] == pytest.approx(4 / 8)


def test_auroc_agrees_with_scikit_learn():
    metrics_module = pytest.importorskip("sklearn.metrics")
    rng = np.random.default_rng(0)
    possible = rng.integers(0, 4, (40, 6)).astype(float)  # small integers: many ties
    impossible = rng.integers(0, 5, (40, 6)).astype(float)
    metrics = field_metrics(possible, impossible)
    labels = np.r_[np.zeros(40), np.ones(40)]
    for reduction in REDUCTIONS:
        scores = np.r_[reduce_surprise(possible, reduction), reduce_surprise(impossible, reduction)]
        assert metrics[f"auroc_{reduction}"] == pytest.approx(
            metrics_module.roc_auc_score(labels, scores)
        )
    called_impossible = np.r_[possible.max(1), impossible.max(1)] > metrics["threshold"]
    assert metrics["absolute_accuracy"] == pytest.approx(
        metrics_module.accuracy_score(labels, called_impossible)
    )


def test_bad_input_is_refused_in_one_line():
    with pytest.raises(ValueError, match=r"must be \[N, T\] on both sides"):
        field_metrics([1, 2], [2, 3])
    with pytest.raises(ValueError, match="unknown surprise reduction 'median'"):
        reduce_surprise(POSSIBLE, "median")
    with pytest.raises(ValueError, match="at least one context length"):
        context_sweep({})


def test_a_context_sweep_gives_each_context_length_its_own_set():
    sweep = context_sweep({8: (IMPOSSIBLE, POSSIBLE), 4: (POSSIBLE, IMPOSSIBLE)})
    assert list(sweep) == [4, 8]
    assert sweep[4] == field_metrics(POSSIBLE, IMPOSSIBLE)
    assert sweep[8]["relative_accuracy_max"] == pytest.approx(1 - 2.5 / 4)


def test_the_formatter_writes_every_column_and_n_a_for_a_note():
    table = format_field_metrics(
        {
            "a/standard": field_metrics(POSSIBLE, IMPOSSIBLE),
            "b/standard": {"n_pairs": 2, "note": "not finite"},
        },
        "concept/variant",
    )
    lines = table.splitlines()
    assert lines[0].count("|") == lines[1].count("|") == lines[2].count("|") == 11
    assert lines[2] == (
        "| a/standard | 4 | 37.5% | 37.5% | 62.5% | 37.5% | 4.1 | 0.406 | 0.406 | 0.500 |"
    )
    assert lines[3].startswith("| b/standard | 2 | n/a |")


def test_quadruplet_benchmarks_get_the_set_from_per_frame_surprise():
    totals = quadruplet_metrics(
        [0, 0, 1, 1],
        reduce_surprise(POSSIBLE, "sum"),
        reduce_surprise(IMPOSSIBLE, "sum"),
        bootstrap=0,
        alpha=ALPHA,
    )
    frames = quadruplet_metrics([0, 0, 1, 1], POSSIBLE, IMPOSSIBLE, bootstrap=0, alpha=ALPHA)
    assert "field_metrics" not in totals
    assert frames.pop("field_metrics") == field_metrics(POSSIBLE, IMPOSSIBLE)
    assert frames == totals


def test_the_report_writes_the_set_per_group_into_summary_json_and_md(tmp_path):
    rng = np.random.default_rng(1)
    consistent = rng.random((8, 5))
    pairs = PairResults(
        concept=["solidity"] * 8,
        variant=["standard", "counterbalanced"] * 4,
        seed=np.arange(8),
        manipulation_frame=np.full(8, 1),
        surprise_consistent=consistent,
        surprise_inconsistent=consistent + rng.random((8, 5)),
    )
    write_report(ReportInputs(pairs, alpha=ALPHA, bootstrap=0), tmp_path, echo=False)
    summary = json.loads((tmp_path / "voe_report" / "summary.json").read_text())
    metrics = summary["field_metrics"]
    assert list(metrics) == ["solidity/standard", "solidity/counterbalanced", "solidity/pooled"]
    standard = pairs.select(np.arange(8) % 2 == 0)
    assert metrics["solidity/standard"] == pytest.approx(
        field_metrics(
            standard.surprise_consistent, standard.surprise_inconsistent, max_from=np.full(4, 2)
        )
    )
    assert metrics["solidity/pooled"]["relative_accuracy_sum"] == 1.0
    markdown = (tmp_path / "voe_report" / "summary.md").read_text()
    assert format_field_metrics(metrics, "concept/variant", max_after_change=True) in markdown


def test_analyze_context_sweep_tables_the_set_of_each_context_lengths_report(tmp_path, capsys):
    rng = np.random.default_rng(2)
    runs = {}
    for context in (4, 8):
        consistent = rng.random((4, 5))
        pairs = PairResults(
            concept=["continuity"] * 4,
            variant=["standard"] * 4,
            seed=np.arange(4),
            manipulation_frame=np.full(4, 1),
            surprise_consistent=consistent,
            surprise_inconsistent=consistent + rng.random((4, 5)) - 0.3,
        )
        write_report(
            ReportInputs(pairs, alpha=ALPHA, bootstrap=0), tmp_path / f"c{context}", echo=False
        )
        runs[context] = pairs
    table = main(
        [
            "analyze",
            "context-sweep",
            "--runs",
            json.dumps({str(c): str(tmp_path / f"c{c}") for c in runs}),
            "--out",
            str(tmp_path / "sweep.md"),
        ]
    )
    expected = format_field_metrics(
        {
            f"continuity/standard @ {c}": field_metrics(
                r.surprise_consistent, r.surprise_inconsistent
            )
            for c, r in runs.items()
        },
        "concept/variant @ context length",
    )
    assert table == expected == (tmp_path / "sweep.md").read_text()
    assert expected in capsys.readouterr().out


def test_the_max_reads_the_frames_from_each_pairs_first_difference():
    """Before the change a pair is one video: there its max is one frame's in both, and the
    first frame's surprise, larger than any later, ties every pair. From the change on, the
    max tells them apart."""
    possible = [[9.0, 0, 1], [9.0, 2, 0], [9.0, 1, 1]]
    impossible = [[9.0, 0, 3], [9.0, 4, 0], [9.0, 1, 0]]
    whole = field_metrics(possible, impossible)
    assert whole["relative_accuracy_max"] == 0.5 and whole["ties_max"] == 3
    after = field_metrics(possible, impossible, max_from=[1, 1, 1])
    # maxima from frame 1: possible 1, 2, 1 against impossible 3, 4, 1 -> right, right, tie
    assert after["relative_accuracy_max"] == pytest.approx(2.5 / 3)
    assert after["ties_max"] == 1
    assert after["relative_accuracy_sum"] == whole["relative_accuracy_sum"]
    assert after["threshold"] == pytest.approx(np.percentile([1, 2, 1], 90))
    with pytest.raises(ValueError, match=r"first_frame must be one frame index in \[0, 2\]"):
        field_metrics(possible, impossible, max_from=[1, 3, 1])


def test_a_quadruplet_row_is_of_quadruplets_as_its_test_is(tmp_path):
    """The field's metrics of a quadruplet are of its n quadruplets (A + B against AB + BA,
    frame by frame), not of its 2n pairs: n and the sum's relative accuracy are summary.csv's
    n and accuracy."""
    rng = np.random.default_rng(3)
    n, frames = 12, 5
    consistent = rng.random((2 * n, frames))
    inconsistent = consistent + rng.normal(0.3, 0.5, (2 * n, frames))
    pairs = PairResults(
        concept=["solidity"] * (2 * n),
        variant=["standard"] * n + ["counterbalanced"] * n,
        seed=np.concatenate([np.arange(n), np.arange(n)]),
        manipulation_frame=np.full(2 * n, 1),
        surprise_consistent=consistent,
        surprise_inconsistent=inconsistent,
    )
    write_report(ReportInputs(pairs, alpha=ALPHA, bootstrap=0), tmp_path, echo=False)
    summary = json.loads((tmp_path / "voe_report" / "summary.json").read_text())
    row = next(r for r in summary["rows"] if r["variant"] == "quadruplet")
    metrics = summary["field_metrics"]["solidity/quadruplet"]
    assert metrics["n_pairs"] == row["n"] == n
    assert metrics["relative_accuracy_sum"] == pytest.approx(row["accuracy"])
    assert metrics == pytest.approx(
        field_metrics(
            consistent[:n] + consistent[n:],
            inconsistent[:n] + inconsistent[n:],
            max_from=np.full(n, 2),
        )
    )
    assert summary["field_metrics"]["solidity/pooled"]["n_pairs"] == 2 * n
