"""CueScorer: the frame-local cues as a parameter-free SurpriseModel, equal to the cue audit's
scores, refusing what it cannot score, and run by ``test`` with no checkpoint on our probes (its
rows follow the cue it is made of), IntPhys and Physical Concepts (IntPhys 2: test_intphys2)."""

import csv
import json

import lightning as L
import pytest
import torch
from helpers import ALPHA
from helpers.locations import TINY_CONFIG

from voe_lightning.audit import video_cues
from voe_lightning.benchmarks.metrics import read_answer_file
from voe_lightning.callbacks import VOEReportCallback
from voe_lightning.callbacks.prediction_writer import IntPhysAnswerWriter
from voe_lightning.cli import main
from voe_lightning.model import CueScorer
from voe_lightning.model.scorers.cue_scorer import CUE_NAMES


@pytest.mark.parametrize("cue", list(CUE_NAMES))
def test_surprise_after_the_manipulation_sums_to_the_audit_score(cue):
    generator = torch.Generator().manual_seed(0)
    frames = torch.randint(0, 256, (3, 6, 8, 8, 3), dtype=torch.uint8, generator=generator)
    mask = torch.randint(0, 3, (3, 6, 8, 8), dtype=torch.uint8, generator=generator)
    manipulation = torch.tensor([0, 2, 4])
    model = CueScorer(cue)
    assert list(model.parameters()) == []
    surprise = model.surprise(frames, mask)
    after = video_cues.counted_frames(CUE_NAMES[cue], manipulation, 6)
    expected = video_cues.score_videos(frames, mask, manipulation)[CUE_NAMES[cue]]
    assert torch.allclose((surprise.double() * after).sum(1), expected, rtol=1e-5)
    assert model.expected_frames(frames).shape == (3, 6, 3, 8, 8)
    assert model.trajectories(frames, mask)["cue"].shape == (3, 6, 2)


def test_unknown_cue_and_a_mask_cue_without_masks_are_refused():
    with pytest.raises(
        ValueError,
        match=r"unknown cue 'colour'; valid cues are: foreground, "
        r"motion, copy_last",
    ):
        CueScorer("colour")
    with pytest.raises(ValueError, match=r"'foreground' counts object pixels and needs masks"):
        CueScorer("foreground").surprise(torch.zeros(1, 3, 4, 4, 3, dtype=torch.uint8))


def test_test_on_our_probes_runs_without_a_checkpoint(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--model",
            "voe_lightning.model.CueScorer",
            "--model.init_args.cue",
            "motion",
            "--trainer.enable_progress_bar",
            "false",
        ]
    )
    report = tmp_path / "runs" / "tiny" / "version_0" / "voe_report"
    assert (report / "summary.json").is_file() and (report / "cues.csv").is_file()
    # the pairs share every frame through the manipulation, so its relative surprise is the
    # motion cue's difference, pair by pair
    rows = [
        row
        for row in csv.DictReader(open(report / "cue_correlations.csv"))
        if row["cue"] == "motion_energy" and row["variant"] == "pooled"
    ]
    assert float(rows[0]["r"]) == pytest.approx(1.0)


@pytest.mark.parametrize("dataset", ["intphys", "physical_concepts"])
def test_test_on_the_other_benchmarks_runs_without_a_checkpoint(dataset, tmp_path):
    """On tiny IntPhys and DeepMind Physical Concepts datasets (``helpers.intphys``,
    ``helpers.physical_concepts``): the report and the benchmark's own metrics are written;
    IntPhys' answer.txt comes from ``predict``."""
    if dataset == "intphys":
        from helpers import intphys as fixtures

        root = fixtures.make_intphys(tmp_path / "data", "dev", labelled=True)
        fixtures.make_intphys(root, "test", labelled=False)
    else:
        from helpers import physical_concepts as fixtures

        root = fixtures.make_dataset(tmp_path / "data")
    trainer = L.Trainer(
        accelerator="cpu",
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[VOEReportCallback(out_dir=str(tmp_path), bootstrap=0, alpha=ALPHA)],
    )
    trainer.test(CueScorer("linear_extrapolation"), datamodule=fixtures.datamodule(root))
    metrics = json.loads((tmp_path / "voe_report" / "benchmark_metrics.json").read_text())
    assert metrics["metrics"]
    if dataset == "intphys":
        trainer = L.Trainer(
            accelerator="cpu",
            logger=False,
            enable_progress_bar=False,
            enable_model_summary=False,
            callbacks=[IntPhysAnswerWriter(tmp_path / "answer.txt")],
        )
        trainer.predict(
            CueScorer("motion"), datamodule=fixtures.datamodule(root), return_predictions=False
        )
        assert len(read_answer_file(tmp_path / "answer.txt")) == 12
