"""A real two-process CPU DDP run (``ddp_spawn`` over gloo) of ``fit`` and ``test``: the VOE
statistics it logs and reports equal the single-process ones on the same pairs and weights."""

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from voe_lightning.cli import main

CONFIG = str(Path(__file__).parent / "configs" / "tiny.yaml")
DDP = ["--trainer.strategy", "ddp_spawn", "--trainer.devices", "2",
       "--trainer.accelerator", "cpu"]
STATISTICS = ("relative_surprise", "t", "p_value", "accuracy")
# float32 summation order differs with the batch sizes; a 2-step model's mean relative
# surprise can be as small as this noise, so t and p are compared only well above it.
NOISE = 1e-6
# 3 pairs per variant of 2 + 3 variants: 15 pairs, which do not divide over two ranks. Each
# pair must still be scored once (Lightning's default sampler would repeat one).
DATA = ["--data", "datamodules.JointDataModule",
        "--data.concepts", "[object_persistence, unchangeableness]",
        "--data.init_args.num_frames", "8",  # unchangeableness' screen needs two frames down
        "--data.init_args.val_pairs", "3", "--data.init_args.test_pairs", "3",
        # float32: bf16 autocast (where the CPU has it) rounds differently per batch size.
        "--model.init_args.precision", "float32"]


# Two gloo ranks that set up a SurpriseModel, gather objects (as the report does) and exit.
# Without the process group destroyed at exit, about half such runs abort (SIGABRT).
EXIT_SCRIPT = """
import os, sys, torch, torch.distributed as dist, torch.multiprocessing as mp
from voe_lightning.model.base import SurpriseModel

class Model(SurpriseModel):
    surprise = expected_frames = trajectories = None

def rank(index, port):
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    dist.init_process_group("gloo", rank=index, world_size=2)
    Model().setup("test")
    gathered = [None, None]
    dist.all_gather_object(gathered, {"surprise": torch.randn(64)})

if __name__ == "__main__":
    mp.spawn(rank, args=(int(sys.argv[1]),), nprocs=2)
"""


def _voe_scalars(run: Path) -> dict[str, float]:
    """The last logged value of every ``voe/...`` scalar of a TensorBoard run."""
    accumulator = EventAccumulator(str(run))
    accumulator.Reload()
    return {tag: accumulator.Scalars(tag)[-1].value
            for tag in accumulator.Tags()["scalars"] if tag.startswith("voe/")}


def _ddp(subcommand: str, *arguments: str, cwd: Path) -> None:
    """``python -m voe_lightning`` in two gloo processes; fails the test with its output."""
    environment = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    result = subprocess.run(
        [sys.executable, "-m", "voe_lightning", subcommand, "--config", CONFIG, *DATA, *DDP,
         *arguments],
        cwd=cwd, env=environment, capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-5000:]
    assert "distributed_backend=gloo" in result.stdout + result.stderr  # really two processes
    assert "All distributed processes registered" in result.stdout + result.stderr


def _report(report: Path) -> tuple[dict[tuple[str, str], dict], dict[tuple, tuple]]:
    """Each summary row by (concept, variant), and each pair's surprise of both videos by
    (concept, variant, seed), from a voe_report directory."""
    rows = json.loads((report / "summary.json").read_text())["rows"]
    with open(report / "pairs.csv", newline="") as handle:
        pairs = {(r["concept"], r["variant"], int(r["seed"])):
                 (float(r["surprise_consistent"]), float(r["surprise_inconsistent"]))
                 for r in csv.DictReader(handle)}
    return {(row["concept"], row["variant"]): row for row in rows}, pairs


def test_ddp_fit_and_test_match_a_single_process(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _ddp("fit", cwd=tmp_path)
    run = tmp_path / "runs" / "tiny" / "version_0"
    checkpoint = run / "checkpoints" / "last.ckpt"
    ddp_fit = _voe_scalars(run)
    cases = {("object_persistence", v) for v in ("standard", "counterbalanced", "pooled")}
    cases |= {("unchangeableness", v) for v in ("position", "color", "shape")}
    assert {f"voe/{c}/{v}/{s}" for c, v in cases for s in STATISTICS} == set(ddp_fit)

    # The last validation of the DDP fit ran on the checkpoint's weights: a single process
    # validating that checkpoint on the same pairs must log the same statistics.
    cli = main(["validate", "--config", CONFIG, *DATA, "--ckpt_path", str(checkpoint)])
    single = {tag: float(value) for tag, value in cli.trainer.callback_metrics.items()
              if tag.startswith("voe/")}
    assert single.keys() == ddp_fit.keys()
    for tag, value in ddp_fit.items():
        if tag.endswith("/relative_surprise"):
            assert value == pytest.approx(single[tag], rel=1e-4, abs=NOISE), tag
        elif abs(ddp_fit[tag.rsplit("/", 1)[0] + "/relative_surprise"]) > 100 * NOISE:
            assert value == pytest.approx(single[tag], rel=1e-4), tag

    # test: the report gathered from both ranks holds the single-process report's pairs, each
    # once, with the same surprise, and so the same statistics in every row.
    _ddp("test", "--ckpt_path", str(checkpoint), cwd=tmp_path)
    ddp_rows, ddp_pairs = _report(run / "voe_report")
    main(["test", "--config", CONFIG, *DATA, "--ckpt_path", str(checkpoint)])
    rows, pairs = _report(run / "voe_report")
    assert rows.keys() == ddp_rows.keys()
    assert rows[("object_persistence", "pooled")]["n"] == 6 and len(pairs) == 15
    assert ddp_pairs.keys() == pairs.keys()
    for key, surprise in pairs.items():
        assert ddp_pairs[key] == pytest.approx(surprise, rel=1e-5, abs=NOISE), key
    for key, row in rows.items():
        assert ddp_rows[key]["n"] == row["n"], key
        for statistic in ("relative_surprise", "accuracy", "auroc"):
            assert ddp_rows[key][statistic] == pytest.approx(row[statistic], rel=1e-4,
                                                             abs=NOISE), (key, statistic)
        if abs(row["relative_surprise"]) > 100 * NOISE:  # t and p of a real difference
            for statistic in ("t", "p_value"):
                assert ddp_rows[key][statistic] == pytest.approx(row[statistic], rel=1e-3,
                                                                 abs=1e-6), (key, statistic)


def test_cpu_ddp_ranks_exit_cleanly(tmp_path):
    """A SurpriseModel's setup makes each gloo rank destroy its process group at exit: six
    runs without one abort (without it, each aborts with probability about one half)."""
    from lightning.fabric.plugins.environments.lightning import find_free_network_port

    script = tmp_path / "ranks.py"
    script.write_text(EXIT_SCRIPT)
    for _ in range(6):
        result = subprocess.run([sys.executable, str(script), str(find_free_network_port())],
                                capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr[-3000:]
