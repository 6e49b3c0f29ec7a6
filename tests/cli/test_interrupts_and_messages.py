"""Issue 73's smaller cases at the command line: Ctrl-C in any command is one line and exit
status 130; a resumed fit may change how its data is loaded; a NaN frame's surprise is named by
concept, variant, seed and frame; a checkpoint holding a pickled object is called that, not
truncated; ``migrate`` says it runs a checkpoint's code (docs/reliability.md)."""

import os
import signal
import subprocess
import sys
import time

import lightning as L
import pytest
import torch
from helpers import refused
from helpers.locations import TINY_CONFIG

from voe_lightning.cli import commands, main

CALLABLE = ["--model", "voe_lightning.model.CallableModel", "--model.init_args.function"]
#: A scorer that says it has started (a file ``started``), then works for a minute.
SLOW_SCORER = """import pathlib, time, torch
def surprise(frames):
    pathlib.Path("started").touch()
    time.sleep(60)
    return torch.zeros(frames.shape[:2])
"""


def nan_at_frame_3(frames: torch.Tensor) -> torch.Tensor:
    """A frame's brightness, but NaN at frame 3 of the batch's first video."""
    surprise = frames.double().mean(dim=(2, 3, 4))
    surprise[0, 3] = float("nan")
    return surprise


class CtrlCAtFitStart(L.Callback):
    """Ctrl-C as the fit begins, before any training step (Lightning's own handling exits 1)."""

    def on_fit_start(self, trainer, pl_module):
        raise KeyboardInterrupt


# ----------------------------------------------------------------------------- Ctrl-C
@pytest.mark.slow
@pytest.mark.parametrize(
    "arguments, line",
    [
        (
            ["check-causality", "--concepts", "[object_persistence]", "--seeds", "1",
             "--size", "32", "--num_frames", "6"],
            "error: check-causality interrupted (Ctrl-C, SIGINT): nothing written and no "
            "verdict (it writes nothing)",
        ),
        (
            ["test", "--config", TINY_CONFIG],
            "error: test interrupted (Ctrl-C, SIGINT): nothing written (no report, no "
            "predictions; one written before is kept)",
        ),
    ],
    ids=["check-causality", "test"],
)  # fmt: skip
def test_ctrl_c_while_a_command_works_is_one_line_and_exit_130(tmp_path, arguments, line):
    (tmp_path / "slow_scorer.py").write_text(SLOW_SCORER)
    environment = {**os.environ, "PYTHONPATH": str(tmp_path), "MUJOCO_GL": "egl"}
    command = [sys.executable, "-m", "voe_lightning", *arguments, *CALLABLE, "slow_scorer.surprise"]
    running = subprocess.Popen(
        command, cwd=tmp_path, env=environment, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while not (tmp_path / "started").exists() and running.poll() is None:
        assert time.monotonic() < deadline, "the scorer was never called"
        time.sleep(0.1)
    running.send_signal(signal.SIGINT)
    _, err = running.communicate(timeout=60)
    assert running.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert [text for text in err.splitlines() if "interrupt" in text.lower()] == [line], err
    assert err.splitlines()[-1] == line
    assert not (tmp_path / "runs" / "tiny" / "version_0" / "voe_report").exists()


def test_ctrl_c_before_a_fit_trains_is_one_line_and_the_handler_is_put_back(workdir, capsys):
    (workdir / "ctrl_c.yaml").write_text(
        "trainer:\n  callbacks+:\n    - class_path: test_interrupts_and_messages.CtrlCAtFitStart\n"
    )
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(SystemExit) as raised:
        main(["fit", "--config", TINY_CONFIG, "--config", "ctrl_c.yaml"])
    assert raised.value.code == 130
    err = capsys.readouterr().err
    assert "Detected KeyboardInterrupt" not in err and "Traceback" not in err, err
    assert err.splitlines()[-1] == (
        "error: fit interrupted (Ctrl-C, SIGINT): nothing saved at step 0 (checkpoints saved "
        "before are kept; a first Ctrl-C while it trains saves a resumable one)"
    )
    assert signal.getsignal(signal.SIGINT) is before  # Lightning's SIG_IGN is not left behind


def test_every_command_says_what_ctrl_c_leaves():
    assert set(commands.INTERRUPTED) == set(commands.COMMANDS)


# ----------------------------------------------------------------------------- resumed fit
@pytest.mark.slow
def test_a_resumed_fit_may_load_its_data_otherwise_but_not_train_on_other_data(workdir, capsys):
    main(["fit", "--config", TINY_CONFIG, "--trainer.max_steps", "1"])
    resume = ["fit", "--config", TINY_CONFIG, "--trainer.max_steps", "2", "--ckpt_path", "last"]
    line = refused(capsys, [*resume, "--data.init_args.batch_size", "3"])
    assert "data.init_args.batch_size: the run trained with 2, given 3" in line
    cli = main(
        [*resume, "--data.init_args.num_workers", "1", "--data.init_args.probe_batch_size", "2"]
    )
    assert cli.trainer.global_step == 2
    assert not (workdir / "runs" / "tiny" / "version_1").exists()


# ----------------------------------------------------------------------------- NaN frame
@pytest.mark.parametrize("subcommand", ["test", "validate"])
def test_a_nan_frame_is_named_by_concept_variant_seed_and_frame(workdir, capsys, subcommand):
    arguments = [subcommand, "--config", TINY_CONFIG, *CALLABLE]
    line = refused(capsys, [*arguments, "test_interrupts_and_messages.nan_at_frame_3"])
    assert line.startswith("error: the model's surprise is nan at frame 3 of the consistent ")
    assert " video of object_persistence " in line and " seed " in line
    assert "surprise must be a finite number at every frame" in line


# ----------------------------------------------------------------------------- checkpoints
def test_a_checkpoint_holding_a_pickled_object_is_called_that_not_truncated(workdir, capsys):
    from fractions import Fraction

    checkpoint = {"hyper_parameters": {"_class_path": "voe_lightning.model.VRNNLRUModel"}}
    torch.save({**checkpoint, "global_step": 1, "note": Fraction(1, 3)}, "pickled.ckpt")
    line = refused(capsys, ["test", "--config", TINY_CONFIG, "--ckpt_path", "pickled.ckpt"])
    assert line.startswith(
        "error: cannot read the checkpoint pickled.ckpt: it holds a pickled object "
        "(fractions.Fraction), which loading weights only refuses"
    )
    assert "truncated" not in line and "weights_only=False" in line


def test_migrate_says_it_runs_a_checkpoints_code(capsys):
    for arguments in (["--help"], ["migrate", "--help"]):
        with pytest.raises(SystemExit):
            main(arguments)
        assert "unpickles checkpoints: trusted runs only" in " ".join(
            capsys.readouterr().out.split()
        )
