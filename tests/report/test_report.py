"""The VOE report: schema of every file, statistics equal to paired_test per group (the
stratified pooled_test for pooled rows) at the run's alpha, pairs.csv round trip, every figure written, degenerate groups explained, and VOEReportCallback in a real
Trainer.test with a small frame-persistence model."""

import csv
import json
import math

import lightning as L
import numpy as np
import pytest
import torch
from helpers import ALPHA
from PIL import Image
from scipy import stats
from tensordict import TensorDict
from torch.utils.data import DataLoader

from voe_lightning import specs
from voe_lightning.callbacks import VOEReportCallback
from voe_lightning.model.base import SurpriseModel
from voe_lightning.probe_datamodule import ProbeDataModule
from voe_lightning.report import ReportInputs, write_report
from voe_lightning.report.figures import PredictionExample
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.tables import SUMMARY_COLUMNS
from voe_lightning.stats.statistics import paired_test, pooled_test, quadruplet_test

T, H, W = 6, 16, 16


def synthetic_results(seed=0):
    """Three tested groups (one zero-variance) and one group with a single pair."""
    rng = np.random.default_rng(seed)
    groups = [
        ("object_persistence", "standard", 10, 1.0),
        ("object_persistence", "counterbalanced", 9, 0.0),
        ("continuity", "standard", 1, 1.0),
        ("solidity", "standard", 4, None),
    ]
    columns = {
        k: []
        for k in (
            "concept",
            "variant",
            "seed",
            "manipulation_frame",
            "surprise_consistent",
            "surprise_inconsistent",
        )
    }
    for concept, variant, n, effect in groups:
        for i in range(n):
            manipulation = int(rng.integers(2, 4))
            consistent = rng.gamma(2.0, 1.0, T)
            inconsistent = consistent.copy()
            # Causal: surprise identical through the manipulation frame (the videos are).
            if effect is None:  # every pair differs by exactly 0.5 just after the manipulation
                inconsistent[manipulation + 1] += 0.5
            else:
                inconsistent[manipulation + 1 :] += rng.normal(effect, 0.5, T - manipulation - 1)
            for key, value in zip(
                columns, (concept, variant, 100 + i, manipulation, consistent, inconsistent)
            ):
                columns[key].append(value)
    # Listed out of specs order on purpose: groups come back in specs order.
    order = np.r_[np.arange(19, 24), np.arange(0, 19)]
    return PairResults(**{k: [v[i] for i in order] for k, v in columns.items()})


def _png_ok(path, min_width=300):
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size[0] >= min_width and image.size[1] >= 150


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    pairs = synthetic_results()
    rng = np.random.default_rng(1)
    frames = np.zeros((T, H, W, 3), np.uint8)
    frames[:, 4:10, 4:10] = [255, 0, 255]
    predictions = [
        PredictionExample(
            "object_persistence", "standard", 100, 3, frames, rng.random((T, 3, H, W))
        )
    ]
    trajectories = {
        video: {"prior": rng.normal(size=(2, T, 8)), "memory": rng.normal(size=(2, T, 3, 4))}
        for video in ("consistent", "inconsistent")
    }
    rows = write_report(
        ReportInputs(
            pairs, predictions=predictions, trajectories=trajectories, alpha=ALPHA, bootstrap=200
        ),
        out,
        echo=False,
    )
    return out / "voe_report", pairs, rows


def test_summary_rows_are_paired_tests_in_specs_order(report):
    directory, results, rows = report
    assert [(r["concept"], r["variant"]) for r in rows] == [
        ("object_persistence", "standard"),
        ("object_persistence", "counterbalanced"),
        ("object_persistence", "pooled"),
        ("object_persistence", "quadruplet"),
        ("continuity", "standard"),
        ("solidity", "standard"),
    ]
    for row, (_, variant, pairs) in zip(rows, results.groups(pooled=True)):
        if row["n"] < 2:
            continue
        if variant == "pooled":
            expected = pooled_test(
                pairs.total_inconsistent,
                pairs.total_consistent,
                pairs.variant,
                bootstrap=200,
                alpha=ALPHA,
            )
        elif variant == "quadruplet":
            expected = _quadruplets_by_hand(results)
        else:
            expected = paired_test(
                pairs.total_inconsistent, pairs.total_consistent, bootstrap=200, alpha=ALPHA
            )
        assert expected.alpha == ALPHA
        assert {k: row[k] for k in expected.as_dict()} == expected.as_dict()
    assert rows[0]["significant"] and not rows[1]["significant"]


def _quadruplets_by_hand(results):
    """The quadruplet test of object persistence's pairs matched by seed (100-108: the
    counterbalanced pairs lack seed 109)."""
    totals = {}
    for i, (concept, variant) in enumerate(zip(results.concept, results.variant)):
        if concept == "object_persistence":
            totals[variant, int(results.seed[i])] = (
                results.total_inconsistent[i],
                results.total_consistent[i],
            )
    first, second = (
        [totals[variant, seed] for seed in range(100, 109)]
        for variant in ("standard", "counterbalanced")
    )
    return quadruplet_test(*np.array(first).T, *np.array(second).T, bootstrap=200, alpha=ALPHA)


def test_pooled_row_is_the_stratified_test_of_both_variants(report):
    """M = (M1 + M2) / 2, SE = 0.5 sqrt(s1^2/n1 + s2^2/n2), Welch-Satterthwaite df, by hand."""
    directory, results, rows = report
    d1, d2 = (
        pairs.relative_surprise
        for concept, variant, pairs in results.groups()
        if concept == "object_persistence"
    )
    pooled = rows[2]
    assert pooled["n"] == 10 + 9 == d1.size + d2.size
    v1, v2 = d1.var(ddof=1) / d1.size, d2.var(ddof=1) / d2.size
    mean, standard_error = (d1.mean() + d2.mean()) / 2, 0.5 * np.sqrt(v1 + v2)
    df = (v1 + v2) ** 2 / (v1**2 / (d1.size - 1) + v2**2 / (d2.size - 1))
    assert pooled["relative_surprise"] == pytest.approx(mean, rel=1e-12)
    assert pooled["t"] == pytest.approx(mean / standard_error, rel=1e-12)
    assert pooled["df"] == pytest.approx(df, rel=1e-12)
    assert pooled["p_value"] == pytest.approx(stats.t.sf(mean / standard_error, df), rel=1e-9)
    # summary.md prints the real-valued df with one decimal, and alpha in the header.
    markdown = (directory / "summary.md").read_text()
    assert f"t({df:.1f}) = {mean / standard_error:.2f}" in markdown
    assert f"| sig. (α = {ALPHA:g}) |" in markdown.splitlines()[0]


def test_a_pooled_row_with_a_variant_of_one_pair_is_explained_not_tested(tmp_path):
    pairs = synthetic_results()
    counterbalanced = [
        (c, v) == ("object_persistence", "counterbalanced")
        for c, v in zip(pairs.concept, pairs.variant)
    ]
    keep = ~np.array(counterbalanced)
    keep[counterbalanced.index(True)] = True  # one counterbalanced pair only
    rows = write_report(
        ReportInputs(pairs.select(keep), alpha=ALPHA, bootstrap=0), tmp_path, echo=False
    )
    pooled = next(r for r in rows if r["variant"] == "pooled")
    assert pooled["t"] is None and pooled["note"] == (
        "no pooled test: counterbalanced has 1 pair (each variant needs at least 2)"
    )


def test_summary_states_each_concepts_verdict(report):
    directory, _, rows = report
    document = json.loads((directory / "summary.json").read_text())
    verdicts = {v["concept"]: v for v in document["verdicts"]}
    assert list(verdicts) == ["object_persistence", "continuity", "solidity"]
    quadruplet = rows[3]
    assert quadruplet["variant"] == "quadruplet" and quadruplet["n"] == 9
    assert verdicts["object_persistence"]["voe"] is (
        quadruplet["p_value"] < ALPHA
        and quadruplet["first_half"] > 0
        and quadruplet["second_half"] > 0
    )
    assert "quadruplet test" in verdicts["object_persistence"]["rule"]
    # continuity and solidity lack their counterbalanced pairs: no pooled test, no verdict.
    assert (
        verdicts["continuity"]["voe"] is None
        and "counterbalanced" in verdicts["continuity"]["verdict"]
    )
    markdown = (directory / "summary.md").read_text()
    assert (
        f"- object_persistence: {'**VOE**' if verdicts['object_persistence']['voe'] else 'no VOE'}"
        in markdown
    )
    assert "- solidity: undecided: no test of counterbalanced, pooled" in markdown


def test_summary_files_schema(report):
    directory, results, rows = report
    with open(directory / "summary.csv", newline="") as handle:
        reader = csv.DictReader(handle)
        assert tuple(reader.fieldnames) == SUMMARY_COLUMNS
        table = list(reader)
    assert len(table) == 6
    assert float(table[0]["t"]) == pytest.approx(rows[0]["t"], rel=1e-12)

    def refuse(constant):
        raise AssertionError(f"non-standard JSON constant {constant}")

    document = json.loads((directory / "summary.json").read_text(), parse_constant=refuse)
    assert document["num_pairs"] == len(results) == 24 and document["num_frames"] == T
    assert [list(r) for r in document["rows"]] == [list(SUMMARY_COLUMNS)] * 6
    assert document["rows"][0]["p_value"] == rows[0]["p_value"]
    markdown = (directory / "summary.md").read_text()
    paired, field = markdown.split("## The field's metrics")
    lines = [line for line in paired.splitlines() if line.startswith("|")]
    assert len(lines) == 2 + 6 and "t(9) = " in markdown and "| M [95% CI] |" in lines[0]
    assert len([line for line in field.splitlines() if line.startswith("|")]) == 2 + 6
    assert len(document["field_metrics"]) == 6


def test_degenerate_groups_are_explained_not_nan(report):
    directory, _, rows = report
    single, constant = rows[4], rows[5]
    assert single["n"] == 1 and single["t"] is None and "no test" in single["note"]
    assert constant["t"] == math.inf and constant["p_value"] == 0.0
    assert "zero variance" in constant["note"]
    markdown = (directory / "summary.md").read_text()
    assert "nan" not in markdown.lower()
    assert "| continuity | standard [1] | 1 | n/a |" in markdown and "t(3) = +inf" in markdown
    assert "[2] zero variance" in markdown
    document = json.loads((directory / "summary.json").read_text())
    assert document["rows"][5]["t"] == "inf" and document["rows"][4]["t"] is None


def test_pairs_csv_round_trips_exactly(report):
    directory, results, _ = report
    with open(directory / "pairs.csv", newline="") as handle:
        header = next(csv.reader(handle))
    assert header[:8] == [
        "concept",
        "variant",
        "seed",
        "manipulation_frame",
        "surprise_consistent",
        "surprise_inconsistent",
        "relative_surprise",
        "first_difference",
    ]
    assert len(header) == 8 + 2 * T and header[-1] == f"surprise_inconsistent_t{T - 1:02d}"
    again = PairResults.from_csv(directory / "pairs.csv")
    assert again.concept == results.concept and again.variant == results.variant
    np.testing.assert_array_equal(again.seed, results.seed)
    np.testing.assert_array_equal(again.manipulation_frame, results.manipulation_frame)
    np.testing.assert_array_equal(again.first_difference, results.first_difference)
    np.testing.assert_array_equal(again.surprise_consistent, results.surprise_consistent)
    np.testing.assert_array_equal(again.surprise_inconsistent, results.surprise_inconsistent)


def test_every_figure_is_written(report):
    directory, _, _ = report
    for name in (
        "histograms.png",
        "surprise_per_frame.png",
        "predictions_object_persistence.png",
        "tsne_object_persistence.png",
    ):
        _png_ok(directory / name)


def test_bad_results_are_refused(tmp_path):
    with pytest.raises(ValueError, match="no probe results"):
        PairResults.from_probe_outputs([])
    output = {
        "concept": torch.tensor([0, 7]),
        "variant": torch.tensor([0, 0]),
        "seed": torch.tensor([1, 2]),
        "manipulation_frame": torch.tensor([3, 3]),
        "surprise_consistent": torch.zeros(2, T),
        "surprise_inconsistent": torch.ones(2, T),
    }
    with pytest.raises(ValueError, match=r"concept indices \[7\] are outside the 5 concept names"):
        PairResults.from_probe_outputs([output])
    with pytest.raises(KeyError, match="lacks \\['seed'\\]"):
        PairResults.from_probe_outputs([{k: v for k, v in output.items() if k != "seed"}])
    with pytest.raises(ValueError, match="disagree with 2 pairs"):
        PairResults(["a", "b"], ["v", "v"], [1, 2], [3], np.zeros((2, T)), np.zeros((2, T)))


# ----------------------------------------------------------------------------- the callback


def _probe(concept, variant, seed):
    """A square that drops, then rests; in the inconsistent video it vanishes at the
    manipulation frame."""
    rng = np.random.default_rng(seed)
    manipulation = int(rng.integers(3, T))  # after the square came to rest
    frames = np.full((T, H, W, 3), 90, np.uint8)
    color = rng.integers(160, 256, 3)
    x = int(rng.integers(0, W - 6))
    for t in range(T):
        top = 2 + 3 * min(t, 2)
        frames[t, top : top + 5, x : x + 5] = color
    inconsistent = frames.copy()
    inconsistent[manipulation:] = 90
    mask = torch.zeros(T, H, W, dtype=torch.uint8)
    record = TensorDict(
        {
            "consistent": {"frames": torch.from_numpy(frames), "mask": mask},
            "inconsistent": {"frames": torch.from_numpy(inconsistent), "mask": mask.clone()},
            "camera": torch.zeros(T, 6),
            "concept": torch.tensor(specs.CONCEPTS.index(concept)),
            "variant": torch.tensor(specs.VARIANTS.index(variant)),
            "manipulation_frame": torch.tensor(manipulation),
            "manipulated_ids": torch.zeros(4, dtype=torch.int64),
            "seed": torch.tensor(seed),
        },
        batch_size=[],
    )
    assert specs.probe_spec(T, H, W, objects=False).is_in(record)
    return record


class UnnamedProbeData(L.LightningDataModule):
    """Five probe pairs per case, without the names that decode their indices."""

    def __init__(self, cases):
        super().__init__()
        self.cases = cases
        self.records = [
            _probe(c, v, 10 * i + j) for i, (c, v) in enumerate(cases) for j in range(5)
        ]

    def test_dataloader(self):
        return DataLoader(self.records, batch_size=4, collate_fn=torch.stack)


class ProbeData(UnnamedProbeData, ProbeDataModule):
    concept_names, variant_names = specs.CONCEPTS, specs.VARIANTS

    def probe_cases(self, split="val"):
        return self.cases


class PersistenceModel(SurpriseModel):
    """Expects each frame to repeat the previous one; surprise is the squared error of that."""

    def __init__(self, return_outputs=True):
        super().__init__()
        self.return_outputs = return_outputs
        self.scale = torch.nn.Parameter(torch.tensor(100.0))

    def expected_frames(self, frames, mask=None, camera=None):
        x = specs.to_model_input(frames)
        return torch.cat([torch.full_like(x[:, :1], 0.5), x[:, :-1]], dim=1)

    def surprise(self, frames, mask=None, camera=None):
        x = specs.to_model_input(frames)
        return self.scale * (x - self.expected_frames(frames)).pow(2).mean(dim=(2, 3, 4))

    def trajectories(self, frames, mask=None, camera=None):
        x = specs.to_model_input(frames).flatten(2)
        return {
            "prior": self.expected_frames(frames).flatten(2),
            "memory": x.cumsum(1) / torch.arange(1, x.shape[1] + 1)[:, None],
        }

    def test_step(self, batch, batch_idx):
        output = {key: batch[key] for key in ("concept", "variant", "seed", "manipulation_frame")}
        output["surprise_consistent"] = self.surprise(batch["consistent", "frames"])
        output["surprise_inconsistent"] = self.surprise(batch["inconsistent", "frames"])
        return output if self.return_outputs else None


def _trainer(tmp_path, callback):
    return L.Trainer(
        default_root_dir=tmp_path,
        callbacks=[callback],
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        accelerator="cpu",
    )


CASES = [
    ("object_persistence", "standard"),
    ("object_persistence", "counterbalanced"),
    ("unchangeableness", "color"),
]


@pytest.mark.slow
def test_callback_writes_the_report_of_a_test_run(tmp_path):
    callback = VOEReportCallback(out_dir=str(tmp_path / "run"), bootstrap=100, alpha=ALPHA)
    _trainer(tmp_path, callback).test(PersistenceModel(), datamodule=ProbeData(CASES))
    directory = tmp_path / "run" / "voe_report"
    assert callback.report_dir == directory
    groups = [(r["concept"], r["variant"], r["n"]) for r in callback.summary]
    assert groups == [
        CASES[0] + (5,),
        CASES[1] + (5,),
        ("object_persistence", "pooled", 10),
        CASES[2] + (5,),
    ]
    assert all(r["significant"] and r["accuracy"] == 1.0 for r in callback.summary)
    # The cue audit scored the very pairs the model was tested on: same groups, same n.
    with open(directory / "cues.csv", newline="") as handle:
        cue_rows = list(csv.DictReader(handle))
    assert {(r["concept"], r["variant"], int(r["n"])) for r in cue_rows} == set(groups)
    motion = {r["variant"]: r for r in cue_rows if r["cue"] == "motion_energy"}
    # These probes change at m itself and are static after it: cues see only t > m, so tied.
    assert (
        float(motion["standard"]["accuracy"]) == 0.5 and "every d = 0" in motion["standard"]["note"]
    )
    foreground = [r for r in cue_rows if r["cue"] == "foreground_pixels"]
    assert all(r["t"] == "" and "no object mask" in r["note"] for r in foreground)  # zero masks
    cue_markdown = (directory / "cues.md").read_text()
    assert "| object_persistence | **pooled** | 10 | 100% / +" in cue_markdown  # model cell first
    for name in (
        "summary.json",
        "summary.csv",
        "summary.md",
        "pairs.csv",
        "histograms.png",
        "surprise_per_frame.png",
        "predictions_object_persistence.png",
        "predictions_unchangeableness.png",
        "tsne_object_persistence.png",
    ):
        assert (directory / name).is_file(), name
    pairs = PairResults.from_csv(directory / "pairs.csv")
    assert len(pairs) == 15 and set(pairs.seed) == {10 * i + j for i in range(3) for j in range(5)}


def test_callback_refuses_missing_outputs_names_and_probes(tmp_path):
    with pytest.raises(TypeError, match="test_step to return the probe_step dict"):
        _trainer(tmp_path, VOEReportCallback(alpha=ALPHA)).test(
            PersistenceModel(return_outputs=False), datamodule=ProbeData(CASES[:1])
        )
    with pytest.raises(TypeError, match="needs a ProbeDataModule .* got UnnamedProbeData"):
        unnamed = UnnamedProbeData(CASES[:1])
        _trainer(tmp_path, VOEReportCallback(alpha=ALPHA)).test(
            PersistenceModel(), datamodule=unnamed
        )
    with pytest.raises(RuntimeError, match="collected no probe results"):
        _trainer(tmp_path, VOEReportCallback(alpha=ALPHA)).test(
            PersistenceModel(), datamodule=ProbeData([])
        )


def test_the_per_frame_figure_ticks_whole_frames_and_keeps_long_titles_whole():
    from voe_lightning.report.figures import per_frame_figure

    variants = ["position", "position_counterbalanced"]
    rng = np.random.default_rng(0)
    results = PairResults(
        ["unchangeableness"] * 8,
        variants * 4,
        np.repeat(np.arange(4), 2),
        rng.integers(3, 8, 8),
        rng.random((8, 15)),
        rng.random((8, 15)),
    )
    figure = per_frame_figure(results)
    figure.canvas.draw()
    box = figure.bbox
    for ax, variant in zip(figure.axes, variants):
        ticks = ax.get_xticks()
        assert np.array_equal(ticks, np.round(ticks)), ticks
        title = ax.title
        assert title.get_text() == f"unchangeableness\n{variant} (n = 4)"
        extent = title.get_window_extent()
        assert box.x0 <= extent.x0 and extent.x1 <= box.x1, (variant, extent, box)
