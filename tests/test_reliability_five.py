"""Issue 59: nothing silently wrong, round five. Seven inputs that gave a wrong result, or
none, without saying so; docs/reliability.md lists each case with its test."""

import json

import pytest
import torch
from locations import TINY_CONFIG

from voe_lightning.cli import main

CALLABLE = ["--model", "voe_lightning.model.CallableModel", "--model.init_args.function"]


def zeros(frames: torch.Tensor) -> torch.Tensor:
    """A constant scorer: no surprise anywhere."""
    return torch.zeros(frames.shape[:2])


# ------------------------------------------------------------------- 1: a figure not drawn
def test_a_model_without_surprise_gets_its_report_without_the_tsne_figure(workdir):
    with pytest.warns(UserWarning, match="differ by at most 0 over every frame") as warned:
        main(["test", "--config", TINY_CONFIG, *CALLABLE, "test_reliability_five.zeros"])
    assert any(str(w.message).endswith("tsne_object_persistence.png not written") for w in warned)
    [report] = workdir.rglob("voe_report")
    summary = json.loads((report / "summary.json").read_text())
    assert [row["n"] for row in summary["rows"]] == [3, 3, 6, 3]  # the statistics, all there
    assert not (report / "tsne_object_persistence.png").exists()
    assert (report / "histograms.png").exists() and (report / "pairs.csv").exists()
