"""The cluster path (docs/cluster.md): a job of two nodes started as SLURM starts one (a process
per task, each told its rank, the world size and the main node by SLURM's environment; gloo on
the CPU) fits and tests as one run, its ranks' pairs in one report; and the templates in
scripts/slurm run: the generation array's tasks and finishing job make one complete store, and
the training job's command parses."""

import csv
import os
import socket
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.locations import REPO, TINY_CONFIG

from voe_lightning.cli import main

SLURM = REPO / "scripts" / "slurm"
#: The store tests/configs/tiny.yaml reads.
TINY_STORE = ["generate", "--root", "data/tiny", "--concepts", "[object_persistence]",
              "--train_examples", "4", "--val_pairs", "2", "--test_pairs", "3",
              "--generalization_pairs", "2", "--num_frames", "8", "--height", "32",
              "--width", "32", "--workers", "1", "--progress", "false"]  # fmt: skip


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _slurm_job(words: list[str], cwd: Path, tasks: int = 2) -> list[str]:
    """Run ``python -m voe_lightning WORDS`` as a SLURM job of ``tasks`` nodes of one task each
    would: one process per task with SLURM's variables; each task's output, once all ended."""
    port = _free_port()
    processes = []
    for rank in range(tasks):
        environment = {
            **os.environ,
            "MUJOCO_GL": "egl",
            "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
            "SLURM_JOB_ID": "4242",
            "SLURM_JOB_NAME": "voe-fit",
            "SLURM_NTASKS": str(tasks),
            "SLURM_NNODES": str(tasks),
            "SLURM_JOB_NUM_NODES": str(tasks),
            "SLURM_NTASKS_PER_NODE": "1",
            "SLURM_PROCID": str(rank),
            "SLURM_LOCALID": "0",
            "SLURM_NODEID": str(rank),
            "SLURM_NODELIST": "localhost",
            "MASTER_ADDR": "127.0.0.1",
            "MASTER_PORT": str(port),
        }
        processes.append(
            subprocess.Popen(
                [sys.executable, "-m", "voe_lightning", *words],
                cwd=cwd,
                env=environment,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
        )
    outputs = [process.communicate(timeout=600)[0] for process in processes]
    for rank, (process, output) in enumerate(zip(processes, outputs)):
        assert process.returncode == 0, f"task {rank}:\n{output[-3000:]}"
    return outputs


def _pairs(report: Path) -> list[tuple[str, str, str]]:
    with open(report / "pairs.csv", newline="") as handle:
        return sorted((r["concept"], r["variant"], r["seed"]) for r in csv.DictReader(handle))


@pytest.mark.slow
def test_a_two_node_slurm_job_fits_and_tests_as_one_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    nodes = ["--trainer.strategy", "ddp", "--trainer.accelerator", "cpu"]
    nodes += ["--trainer.devices", "1", "--trainer.num_nodes", "2"]
    main(TINY_STORE)  # before the job: each node's rank 0 would make it otherwise
    fitted = _slurm_job(["fit", "--config", TINY_CONFIG, *nodes], tmp_path)
    assert "GLOBAL_RANK: 0, MEMBER: 1/2" in fitted[0] and "GLOBAL_RANK: 1, MEMBER: 2/2" in fitted[1]
    checkpoint = tmp_path / "runs" / "tiny" / "version_0" / "checkpoints" / "last.ckpt"
    assert checkpoint.is_file() and not (tmp_path / "runs" / "tiny" / "version_1").exists()

    _slurm_job(["test", "--config", TINY_CONFIG, *nodes, "--ckpt_path", str(checkpoint)], tmp_path)
    report = next((tmp_path / "runs" / "tiny" / "version_0").rglob("voe_report"))
    merged = _pairs(report)
    main(["test", "--config", TINY_CONFIG, "--ckpt_path", str(checkpoint)])
    alone = _pairs(max((tmp_path / "runs" / "tiny").rglob("voe_report"), key=os.path.getmtime))
    assert merged == alone and len(merged) >= 6  # each pair once, from both ranks


def _script(name: str, environment: dict[str, str], cwd: Path) -> str:
    done = subprocess.run(
        ["bash", str(SLURM / name)],
        cwd=cwd,
        env={**os.environ, "MUJOCO_GL": "egl", **environment},
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


@pytest.mark.slow
def test_the_generation_array_and_its_finishing_job_make_one_store(tmp_path):
    store = {"ROOT": str(tmp_path / "store"), "TRAIN_EXAMPLES": "1", "VAL_PAIRS": "1"}
    store |= {"TEST_PAIRS": "1", "GENERALIZATION_PAIRS": "1", "SLURM_CPUS_PER_TASK": "1"}
    tasks = [
        _script(
            "generate.sbatch",
            {**store, "SLURM_ARRAY_TASK_ID": str(i), "SLURM_ARRAY_TASK_COUNT": "2"},
            tmp_path,
        )
        for i in range(2)
    ]
    assert all("shards generated" in output for output in tasks), tasks
    finished = _script("generate.sbatch", {**store, "FINISH": "1"}, tmp_path)
    assert ": 0 shards generated" in finished, finished  # the tasks made every shard


def test_the_training_jobs_command_parses(tmp_path, monkeypatch):
    """fit.sbatch's srun command, as srun would run it on a job of 2 nodes of 4 tasks."""
    fake = tmp_path / "bin" / "srun"
    fake.parent.mkdir()
    fake.write_text('#!/usr/bin/env bash\nprintf "%s\\n" "$@"\n')
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    environment = {
        "PATH": f"{fake.parent}{os.pathsep}{os.environ['PATH']}",
        "SLURM_JOB_NUM_NODES": "2",
        "SLURM_NTASKS_PER_NODE": "4",
        "SLURM_CPUS_PER_TASK": "8",
    }
    for resume in ("", "last"):
        words = _script("fit.sbatch", {**environment, "RESUME": resume}, REPO).splitlines()
        assert words[:4] == ["python", "-m", "voe_lightning", "fit"], words
        assert words[words.index("--trainer.num_nodes") + 1] == "2"
        assert ("--ckpt_path" in words) == bool(resume)
        if resume:
            del words[words.index("--ckpt_path") : words.index("--ckpt_path") + 2]
        monkeypatch.chdir(REPO)
        monkeypatch.setattr(sys, "argv", ["python -m voe_lightning"])
        with pytest.raises(SystemExit) as parsed:
            main([*words[3:], "--print_config"])
        assert parsed.value.code in (None, 0)
