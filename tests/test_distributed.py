"""A real two-process CPU DDP run (``ddp_spawn`` over gloo) of ``fit`` and ``test``: the VOE
statistics it logs and reports equal the single-process ones on the same pairs and weights, up
to what float32 noise in each video's surprise can change them.

DDP must preserve each row's n exactly and its sums of d and d^2, so M, t and p, up to float
noise: the two ranks score their pairs in other batches than one process does, and float32
rounding of a video's surprise S (a sum of positive KL terms) differs with the batch. A tiny
model after two steps separates its videos by about 1e-4 of an S near 2, so t and p are ratios
of numbers near that noise. Each statistic is therefore compared with a tolerance propagated
from the noise of S (``_tolerances``), tight where |M| is far above it and loose where it is
not. That noise is measured on the CPU the test runs on (``_batch_noise``: the same pairs
scored one at a time and all at once), so the bound holds on AVX2, AVX512 and AVX512-BF16
kernels alike, which round differently."""

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import ALPHA
from helpers.locations import TINY_CONFIG
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from voe_lightning import specs
from voe_lightning.cli import main
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.tables import summarize
from voe_lightning.specs import QUADRUPLET_ROWS

DDP = ["--trainer.strategy", "ddp_spawn", "--trainer.devices", "2", "--trainer.accelerator", "cpu"]
STATISTICS = ("relative_surprise", "t", "p_value", "accuracy", "n")
#: Least float32 noise of a video's surprise S between two batch compositions, relative to S
#: (a float32 step of S is 1.2e-7 of it): measured 7.7e-8 between these DDP ranks and one
#: process and at most 1.9e-7 over batch sizes 1 to 15 on an AVX512-BF16 AMD EPYC; implied
#: about 1e-7 by an AVX512-BF16 Xeon's run (its M moved by 1.8e-7 of an S near 2). The test
#: takes the larger of this and MARGIN times what it measures on its own CPU (``_batch_noise``).
RELATIVE_NOISE = 2e-6
MARGIN = 10
ABSOLUTE_NOISE = 1e-6  # for a video whose S is near 0
#: TensorBoard stores scalars as float32: their own rounding, relative.
LOGGED_ROUNDING = 1e-6
# 3 pairs per variant of 3 + 6 variants: 27 pairs, which do not divide over two ranks. Each
# pair must still be scored once (Lightning's default sampler would repeat one).
DATA = [
    "--data",
    "voe_lightning.datamodules.VOEDataModule",
    "--data.concepts",
    "[continuity, unchangeableness]",
    "--data.init_args.num_frames",
    "8",  # unchangeableness' screen needs two frames down
    "--data.init_args.val_pairs",
    "3",
    "--data.init_args.test_pairs",
    "3",
    # float32: bf16 autocast (where the CPU has it) rounds differently per batch size.
    "--model.init_args.precision",
    "float32",
]


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
    return {
        tag: accumulator.Scalars(tag)[-1].value
        for tag in accumulator.Tags()["scalars"]
        if tag.startswith("voe/")
    }


def _ddp(subcommand: str, *arguments: str, cwd: Path) -> None:
    """``python -m voe_lightning`` in two gloo processes; fails the test with its output."""
    environment = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "voe_lightning",
            subcommand,
            "--config",
            TINY_CONFIG,
            *DATA,
            *DDP,
            *arguments,
        ],
        cwd=cwd,
        env=environment,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-5000:]
    assert "distributed_backend=gloo" in result.stdout + result.stderr  # really two processes
    assert "All distributed processes registered" in result.stdout + result.stderr


def _report(report: Path) -> tuple[dict[tuple[str, str], dict], dict[tuple, tuple]]:
    """Each summary row by (concept, variant), and each pair's surprise of both videos by
    (concept, variant, seed), from a voe_report directory."""
    rows = json.loads((report / "summary.json").read_text())["rows"]
    with open(report / "pairs.csv", newline="") as handle:
        pairs = {
            (r["concept"], r["variant"], int(r["seed"])): (
                float(r["surprise_consistent"]),
                float(r["surprise_inconsistent"]),
            )
            for r in csv.DictReader(handle)
        }
    return {(row["concept"], row["variant"]): row for row in rows}, pairs


def _validation_pairs(cli, one_at_a_time: bool = False) -> PairResults:
    """The per-pair surprise of the validation pairs under the single-process CLI's model, in
    the DataModule's batches or one pair per batch."""
    model, datamodule = cli.model.eval(), cli.datamodule
    batches = datamodule.val_dataloader()
    if one_at_a_time:
        batches = [
            batch[index : index + 1] for batch in batches for index in range(batch.batch_size[0])
        ]
    with torch.no_grad():
        outputs = [model.probe_step(batch) for batch in batches]
    return PairResults.from_probe_outputs(
        outputs, datamodule.concept_names, datamodule.variant_names
    )


def _batch_noise(batched: PairResults, alone: PairResults) -> float:
    """The relative float noise of a video's surprise S to allow on this CPU: MARGIN times the
    largest relative change of S between scoring the pairs in batches and one at a time (what
    DDP changes: each rank batches other pairs), and at least RELATIVE_NOISE."""
    assert list(batched.seed) == list(alone.seed)
    measured = 0.0
    for side in ("surprise_consistent", "surprise_inconsistent"):
        together = getattr(batched, side).sum(axis=1)
        apart = getattr(alone, side).sum(axis=1)
        change = abs(together - apart) / np.maximum(abs(together), 1e-3)
        measured = max(measured, float(change.max()))
    return max(RELATIVE_NOISE, MARGIN * measured)


def _rows(pairs: PairResults) -> dict[tuple[str, str], dict]:
    return {
        (row["concept"], row["variant"]): row for row in summarize(pairs, bootstrap=0, alpha=ALPHA)
    }


def _tolerances(
    pairs: PairResults, statistics: tuple[str, ...], noise: float
) -> dict[tuple[str, str], dict[str, float]]:
    """How far float noise in each video's surprise S (``noise`` of S) can move each row's
    statistics: the sum over videos of the largest change when that video's S moves by its
    noise up or down (the first-order bound of every video off at once), doubled."""
    reference = _rows(pairs)
    tolerance = {key: dict.fromkeys(statistics, 0.0) for key in reference}
    for side in ("surprise_consistent", "surprise_inconsistent"):
        totals = getattr(pairs, side).sum(axis=1)
        for index, total in enumerate(totals):
            changes = {key: dict.fromkeys(statistics, 0.0) for key in reference}
            for sign in (1.0, -1.0):
                surprise = getattr(pairs, side).copy()
                surprise[index, -1] += sign * (noise * abs(total) + ABSOLUTE_NOISE)
                moved = _rows(PairResults(**{**vars(pairs), side: surprise}))
                for key, row in moved.items():
                    for statistic in statistics:
                        change = abs(row[statistic] - reference[key][statistic])
                        changes[key][statistic] = max(changes[key][statistic], change)
            for key in reference:
                for statistic in statistics:
                    tolerance[key][statistic] += changes[key][statistic]
    return {key: {s: 2.0 * value for s, value in row.items()} for key, row in tolerance.items()}


def _assert_close(
    actual: float, expected: float, tolerance: float, what, zero_within_noise: bool = False
) -> None:
    """|actual - expected| within ``tolerance``. A t or d_z is undefined (NaN) when every d is
    exactly 0, which float noise can make of one side only where M is within its noise of 0
    (``zero_within_noise``): only then may either side be NaN (summary.json writes it 'nan')."""
    actual, expected = float(actual), float(expected)
    if zero_within_noise and (math.isnan(actual) or math.isnan(expected)):
        return
    assert abs(actual - expected) <= tolerance + LOGGED_ROUNDING * abs(expected), (
        f"{what}: {actual} vs {expected}, tolerance {tolerance:.3g} from float noise of S"
    )


@pytest.mark.slow
def test_ddp_fit_and_test_match_a_single_process(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _ddp("fit", cwd=tmp_path)
    run = tmp_path / "runs" / "tiny" / "version_0"
    checkpoint = run / "checkpoints" / "last.ckpt"
    ddp_fit = _voe_scalars(run)
    cases = {("continuity", v) for v in ("standard", "counterbalanced", "paper", "pooled")}
    cases |= {("unchangeableness", v) for v in specs.VERDICT_VARIANTS["unchangeableness"]}
    quadruplet_tags = {tag for tag in ddp_fit if tag.split("/")[2] in QUADRUPLET_ROWS}
    assert {f"voe/{c}/{v}/{s}" for c, v in cases for s in STATISTICS} == (
        set(ddp_fit) - quadruplet_tags
    )

    # The last validation of the DDP fit ran on the checkpoint's weights: a single process
    # validating that checkpoint on the same pairs must log the same statistics, each pair
    # once (n), up to the float noise of the per-pair surprise of that single process.
    cli = main(["validate", "--config", TINY_CONFIG, *DATA, "--ckpt_path", str(checkpoint)])
    single = {
        tag: float(value)
        for tag, value in cli.trainer.callback_metrics.items()
        if tag.startswith("voe/")
    }
    assert single.keys() == ddp_fit.keys()
    validation = _validation_pairs(cli)
    assert len(validation) == 27
    noise = _batch_noise(validation, _validation_pairs(cli, one_at_a_time=True))
    expected, tolerances = _rows(validation), _tolerances(validation, STATISTICS[:-1], noise)
    for (concept, variant), tolerance in tolerances.items():
        prefix = f"voe/{concept}/{variant}"
        if variant in QUADRUPLET_ROWS:  # matched by seed over both ranks' pairs, as in one
            if expected[(concept, variant)]["n"] < 2:
                assert f"{prefix}/n" not in ddp_fit
                continue
            assert {f"{prefix}/{s}" for s in (*STATISTICS, "first_half", "second_half")} <= (
                quadruplet_tags
            )
        assert ddp_fit[f"{prefix}/n"] == single[f"{prefix}/n"] == expected[(concept, variant)]["n"]
        row = expected[(concept, variant)]
        zero = abs(row["relative_surprise"]) <= tolerance["relative_surprise"]
        for statistic, allowed in tolerance.items():
            tag = f"{prefix}/{statistic}"
            _assert_close(single[tag], row[statistic], allowed, tag, zero)
            _assert_close(ddp_fit[tag], single[tag], allowed, tag, zero)

    # test: the report gathered from both ranks holds the single-process report's pairs, each
    # once, with the same surprise up to float noise, and so the same statistics in every row
    # up to what that noise can change.
    _ddp("test", "--ckpt_path", str(checkpoint), cwd=tmp_path)
    ddp_rows, ddp_pairs = _report(run / "voe_report")
    main(["test", "--config", TINY_CONFIG, *DATA, "--ckpt_path", str(checkpoint)])
    rows, pairs = _report(run / "voe_report")
    assert rows.keys() == ddp_rows.keys()
    assert rows[("continuity", "pooled")]["n"] == 6 and len(pairs) == 27
    assert ddp_pairs.keys() == pairs.keys()
    for key, surprise in pairs.items():
        assert ddp_pairs[key] == pytest.approx(surprise, rel=noise, abs=ABSOLUTE_NOISE), key
    compared = ("relative_surprise", "sd", "t", "df", "p_value", "accuracy", "auroc", "d_z")
    tolerances = _tolerances(
        PairResults.from_csv(run / "voe_report" / "pairs.csv"), compared, noise
    )
    for key, row in rows.items():
        assert ddp_rows[key]["n"] == row["n"], key
        zero = abs(row["relative_surprise"]) <= tolerances[key]["relative_surprise"]
        for statistic, allowed in tolerances[key].items():
            _assert_close(ddp_rows[key][statistic], row[statistic], allowed, (key, statistic), zero)


@pytest.mark.slow
def test_cpu_ddp_ranks_exit_cleanly(tmp_path):
    """A SurpriseModel's setup makes each gloo rank destroy its process group at exit: six
    runs without one abort (without it, each aborts with probability about one half)."""
    from lightning.fabric.plugins.environments.lightning import find_free_network_port

    script = tmp_path / "ranks.py"
    script.write_text(EXIT_SCRIPT)
    for _ in range(6):
        result = subprocess.run(
            [sys.executable, str(script), str(find_free_network_port())],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert result.returncode == 0, result.stderr[-3000:]
