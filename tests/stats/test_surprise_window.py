"""The surprise window (``voe_lightning.stats.surprise_window``): each pair's first difference from
its frames, a video's surprise summed over the window by hand on a toy pair, the configs it
accepts and refuses, and a test run whose report names the window beside all frames."""

import csv
import json

import numpy as np
import pytest
import torch
from helpers import ALPHA
from helpers.locations import TINY_CONFIG

from voe_lightning.cli import main
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.tables import summarize
from voe_lightning.stats.surprise_window import (
    SurpriseWindow,
    first_difference,
    surprise_window,
    video_surprise,
)


def test_the_first_difference_is_the_first_frame_at_which_a_pairs_videos_differ():
    consistent = torch.zeros(3, 5, 2, 2, 3, dtype=torch.uint8)
    inconsistent = consistent.clone()
    inconsistent[0, 3, 1, 0, 2] = 1  # one value of frame 3
    inconsistent[1, 1:] = 255  # every frame from 1
    # pair 2 never differs: its window starts after the last frame
    assert first_difference(consistent, inconsistent).tolist() == [3, 1, 5]


def _toy() -> PairResults:
    """Two standard pairs of five frames: the videos differ from frame 2 and frame 3."""
    consistent = np.array([[1.0, 2.0, 3.0, 4.0, 5.0], [1.0, 1.0, 1.0, 1.0, 1.0]])
    inconsistent = np.array([[1.0, 2.0, 7.0, 4.0, 15.0], [1.0, 1.0, 1.0, 6.0, 9.0]])
    return PairResults(
        concept=["continuity"] * 2,
        variant=["standard"] * 2,
        seed=[0, 1],
        manipulation_frame=[1, 1],
        surprise_consistent=consistent,
        surprise_inconsistent=inconsistent,
        first_difference=[2, 3],
    )


def test_a_window_sums_the_frames_from_the_first_difference_by_hand():
    results = _toy()
    windowed = results.windowed(surprise_window({"start": "first_difference", "frames": 2}))
    # pair 0: frames 2, 3 -> consistent 3 + 4, inconsistent 7 + 4;
    # pair 1: frames 3, 4 -> consistent 1 + 1, inconsistent 6 + 9
    np.testing.assert_array_equal(windowed.total_consistent, [7.0, 2.0])
    np.testing.assert_array_equal(windowed.total_inconsistent, [11.0, 15.0])
    np.testing.assert_array_equal(windowed.relative_surprise, [4.0, 13.0])
    # all frames: pair 0's persistent difference at frame 4 counts too
    np.testing.assert_array_equal(results.relative_surprise, [14.0, 13.0])
    assert results.windowed(SurpriseWindow()).relative_surprise.tolist() == [14.0, 13.0]
    row = summarize(windowed, bootstrap=0, alpha=ALPHA)[0]
    assert row["relative_surprise"] == pytest.approx(8.5) and row["n"] == 2
    # a window past the last frame keeps what there is; without first_difference, m + 1
    late = results.windowed(SurpriseWindow(frames=10))
    np.testing.assert_array_equal(late.relative_surprise, [14.0, 13.0])
    unknown = PairResults(
        results.concept,
        results.variant,
        results.seed,
        [2, 0],
        results.surprise_consistent,
        results.surprise_inconsistent,
    )
    assert unknown.first_difference.tolist() == [3, 1]


def test_a_videos_surprise_is_made_in_one_place_for_tensors_and_arrays():
    per_frame = torch.arange(12, dtype=torch.float32).reshape(2, 6)
    assert torch.equal(video_surprise(per_frame), per_frame.sum(-1))
    assert video_surprise(per_frame).dtype == torch.float64  # summed in float64 (issue 73)
    window = SurpriseWindow(2)
    windowed = video_surprise(per_frame, window, torch.tensor([1, 5]))
    assert windowed.tolist() == [1.0 + 2.0, 11.0]  # frames 1-2; frame 5 only (the video ends)
    assert np.array_equal(
        video_surprise(per_frame.double().numpy(), window, [1, 5]), windowed.double().numpy()
    )
    with pytest.raises(ValueError, match="needs each pair's first difference"):
        video_surprise(per_frame, window)


@pytest.mark.parametrize(
    "value",
    [
        "some",
        {"start": "manipulation_frame", "frames": 3},
        {"start": "first_difference", "frames": 0},
        {"start": "first_difference", "frames": 2.5},
        {"start": "first_difference"},
    ],
)
def test_a_window_that_is_not_one_is_refused_naming_what_is_valid(value):
    with pytest.raises(ValueError, match=r"surprise_window .* valid: 'all'.*first_difference"):
        surprise_window(value)


def test_a_window_reads_back_as_the_config_gave_it():
    for value in ("all", {"start": "first_difference", "frames": 4}):
        assert surprise_window(value).as_config() == value
    assert surprise_window(None).all_frames


def test_the_report_names_its_window_beside_all_frames(tmp_path, monkeypatch):
    """``test --surprise_window`` (a parameter-free scorer: no checkpoint) writes the paper's
    rows over all frames and, beside them, the window's, each naming what it summed."""
    monkeypatch.chdir(tmp_path)
    model = [
        "--model",
        "voe_lightning.model.CueScorer",
        "--model.init_args.cue",
        "motion",
        "--trainer.enable_progress_bar",
        "false",
    ]
    main(["test", "--config", TINY_CONFIG, *model])
    report = tmp_path / "runs" / "tiny" / "version_0" / "voe_report"
    assert "Surprise window: all frames (the paper's)." in (report / "summary.md").read_text()
    summary = json.loads((report / "summary.json").read_text())
    assert summary["surprise_window"] == "all" and "window" not in summary
    assert not (report / "summary_window.csv").exists()
    all_rows = summary["rows"]

    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            *model,
            "--surprise_window",
            "{start: first_difference, frames: 2}",
        ]
    )
    report = tmp_path / "runs" / "tiny" / "version_1" / "voe_report"
    markdown = (report / "summary.md").read_text()
    assert "## Surprise window: 2 frames from the pair's first difference" in markdown
    assert "S = sum over frames of" in markdown  # the paper's table first, unchanged
    assert "S = sum over the 2 frames from the pair's first difference" in markdown
    summary = json.loads((report / "summary.json").read_text())
    assert summary["surprise_window"] == {"start": "first_difference", "frames": 2}
    assert summary["rows"] == all_rows
    pairs = PairResults.from_csv(report / "pairs.csv")
    expected = summarize(pairs.windowed(SurpriseWindow(2)), bootstrap=2000, alpha=ALPHA)
    window = summary["window"]
    assert window["video_surprise"].startswith("sum over the 2 frames from the pair's first")
    assert [row["relative_surprise"] for row in window["rows"]] == pytest.approx(
        [row["relative_surprise"] for row in expected]
    )
    with open(report / "summary_window.csv", newline="") as handle:
        assert len(list(csv.DictReader(handle))) == len(expected)
    # the first differences are the probes' own: after the manipulation frame
    assert bool((pairs.first_difference > pairs.manipulation_frame).all())


def test_validation_curves_log_the_window_beside_all_frames():
    """``VOEProbeCallback(surprise_window=...)`` logs ``voe/...`` over all frames, as before,
    and ``voe_window/...`` over the window; here by hand on the toy pairs."""
    from types import SimpleNamespace

    from voe_lightning import specs
    from voe_lightning.callbacks import VOEProbeCallback
    from voe_lightning.probe_datamodule import ProbeDataModule

    class Probes(ProbeDataModule):
        concept_names, variant_names = specs.CONCEPTS, specs.VARIANTS

        def probe_cases(self, split="val"):
            return [("continuity", "standard")]

    class Module:
        device = torch.device("cpu")
        logged: dict = {}

        def log(self, name, value, **kwargs):
            self.logged[name] = value

    results, module = _toy(), Module()
    trainer = SimpleNamespace(datamodule=Probes(), sanity_checking=False, global_step=0)
    callback = VOEProbeCallback(print_table=False, surprise_window=SurpriseWindow(2), alpha=ALPHA)
    callback.on_validation_epoch_start(trainer, module)
    outputs = {
        "concept": torch.tensor([specs.CONCEPTS.index("continuity")] * 2),
        "variant": torch.tensor([specs.VARIANTS.index("standard")] * 2),
        "manipulation_frame": torch.tensor([1, 1]),
        "first_difference": torch.tensor([2, 3]),
        "surprise_consistent": torch.from_numpy(results.surprise_consistent),
        "surprise_inconsistent": torch.from_numpy(results.surprise_inconsistent),
    }
    callback.on_validation_batch_end(trainer, module, outputs, None, 0)
    callback.on_validation_epoch_end(trainer, module)
    assert module.logged["voe/continuity/standard/relative_surprise"] == pytest.approx(13.5)
    assert module.logged["voe_window/continuity/standard/relative_surprise"] == pytest.approx(8.5)
    assert callback.last[("continuity", "standard")]["relative_surprise"] == pytest.approx(13.5)
