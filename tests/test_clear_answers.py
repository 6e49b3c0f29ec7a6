"""Clear answers (issue 59): a misleading or silent answer becomes one line naming the value and
what is valid, or what a user expects; files and signals behave as docs/reliability.md says.
Each test drives one case in its smallest form; docs/reliability.md lists each with its test."""

import csv
import errno
import json
import os
import signal
import socket
import subprocess
from pathlib import Path
from types import SimpleNamespace

import lightning as L
import numpy as np
import pytest
import torch
import yaml
from helpers import refused
from helpers.intphys import datamodule as intphys_datamodule
from helpers.intphys import make_intphys
from helpers.intphys2 import make_root
from helpers.locations import REPO, TINY_CONFIG
from helpers.runs import curve_runs
from jsonargparse import Namespace
from PIL import Image

from voe_lightning import run_folders
from voe_lightning.benchmarks.intphys.reader import read_png
from voe_lightning.benchmarks.intphys2.datamodule import IntPhys2DataModule
from voe_lightning.benchmarks.intphys2.reader import read_metadata
from voe_lightning.benchmarks.reader import BenchmarkDataError
from voe_lightning.callbacks import InterruptCheckpoint
from voe_lightning.callbacks.checkpoint_io import WholeCheckpointIO
from voe_lightning.cli import main
from voe_lightning.cli.user_errors import DEBUG_VARIABLE
from voe_lightning.data.store import files, generation
from voe_lightning.model import CallableModel, CueScorer
from voe_lightning.model.base import check_real_surprise

CALLABLE = ["--model", "voe_lightning.model.CallableModel", "--model.init_args.function"]


def brightness(frames: torch.Tensor) -> torch.Tensor:
    return frames.float().mean(dim=(2, 3, 4))


def returns_complex(frames: torch.Tensor) -> torch.Tensor:
    return torch.fft.fft(brightness(frames), dim=1)


def returns_nan(frames: torch.Tensor) -> torch.Tensor:
    return torch.full(frames.shape[:2], float("nan"))


def raises_value_error(frames: torch.Tensor) -> torch.Tensor:
    raise ValueError("my model cannot take 6 frames")


class FrameChange(torch.nn.Module):
    """docs/your_model.md's option 2: an nn.Module built at import, its weights trainable."""

    def __init__(self) -> None:
        super().__init__()
        self.scale = torch.nn.Linear(1, 1)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return self.scale(brightness(frames)[..., None])[..., 0]


frame_change = FrameChange()


class WrongExpectation(CallableModel):
    """Its expected_frames are the uint8 input [B, T, H, W, 3], not [B, T, 3, H, W] in [0, 1]."""

    def expected_frames(self, frames, mask=None, camera=None, objects=None):
        return frames


class SigtermAtTestBatch(L.Callback):
    """Sends this process SIGTERM as the first test batch starts (kill, timeout)."""

    def on_test_batch_start(self, trainer, pl_module, batch, batch_idx, dataloader_idx=0):
        os.kill(os.getpid(), signal.SIGTERM)


def _test(*extra: str) -> list[str]:
    return ["test", "--config", TINY_CONFIG, "--trainer.enable_progress_bar", "false", *extra]


# ----------------------------------------------------------------------------- misleading, silent
def test_complex_surprise_is_refused_naming_the_callable_and_the_dtype(workdir, capsys):
    line = refused(capsys, _test(*CALLABLE, "test_clear_answers.returns_complex"))
    assert "test_clear_answers.returns_complex returned complex surprise (torch.complex64)" in line
    with pytest.raises(ValueError, match=r"MyModel returned complex surprise \(torch.complex128\)"):
        check_real_surprise(torch.zeros(2, 3, dtype=torch.complex128), "MyModel")


def test_check_causality_of_nan_surprise_says_it_cannot_be_checked(capsys):
    line = refused(
        capsys,
        [
            "check-causality",
            "--concepts",
            "[object_persistence]",
            "--seeds",
            "1",
            "--num_frames",
            "6",
            *CALLABLE,
            "test_clear_answers.returns_nan",
        ],
    )
    assert (
        "CallableModel of test_clear_answers.returns_nan's causality cannot be checked: its "
        "surprise is not finite on object_persistence's probes" in line
    )
    assert "causal (surprise identical" not in capsys.readouterr().out


def test_a_mask_cue_on_a_benchmark_without_masks_is_refused_naming_the_cues_that_work(
    tmp_path, capsys
):
    for data, name in (
        (intphys_datamodule(make_intphys(tmp_path / "intphys")), "IntPhys"),
        (IntPhys2DataModule(root=str(tmp_path), num_frames=4, height=16, width=16), "IntPhys 2"),
    ):
        scorer = CueScorer("foreground")
        scorer._trainer = SimpleNamespace(datamodule=data)
        with pytest.raises(ValueError) as raised:
            scorer.setup("test")
        assert str(raised.value) == (
            f"CueScorer cue 'foreground' counts object pixels in the masks, and {name} has no "
            "masks (its videos' masks would all be zero): choose one of motion, copy_last, "
            "linear_extrapolation, novelty"
        )
    CueScorer("motion").setup("test")  # a frame cue runs on them
    root = make_root(tmp_path / "intphys2")
    line = refused(
        capsys,
        [
            "test",
            "--config",
            str(REPO / "configs" / "intphys2.yaml"),
            "--model",
            "voe_lightning.model.CueScorer",
            "--model.init_args.cue",
            "foreground",
            "--data.init_args.root",
            str(root),
            "--data.init_args.num_frames",
            "4",
            "--data.init_args.height",
            "16",
            "--data.init_args.width",
            "16",
            "--data.init_args.num_workers",
            "0",
            "--data.init_args.cache_dir",
            "null",
            "--trainer.logger.init_args.save_dir",
            str(tmp_path / "runs"),
        ],
    )
    assert "CueScorer cue 'foreground' counts object pixels in the masks, and IntPhys 2" in line


def test_a_16_bit_grayscale_intphys_frame_is_scaled_to_8_bits_not_clipped(tmp_path):
    levels = np.array([[0, 257, 32896], [65278, 65535, 1000]], dtype=np.uint16)
    Image.fromarray(levels).save(tmp_path / "scene_001.png")
    assert Image.open(tmp_path / "scene_001.png").mode.startswith("I")
    frame = read_png(tmp_path / "scene_001.png")
    assert frame.dtype == np.uint8 and frame.shape == (2, 3, 3)
    assert frame[..., 0].tolist() == [[0, 1, 128], [254, 255, 4]]  # v / 257, rounded
    assert (frame[..., 0] == frame[..., 2]).all()
    Image.fromarray(np.full((2, 3), 200, np.uint8)).save(tmp_path / "scene_002.png")
    assert (read_png(tmp_path / "scene_002.png") == 200).all()  # 8-bit frames as before


def test_intphys2_metadata_line_numbers_count_blank_lines_and_paths_stay_in_the_dataset(
    tmp_path,
):
    root = make_root(tmp_path / "intphys2")
    metadata = root / "Main" / "metadata.csv"
    header, first, second, *rest = metadata.read_text().splitlines()
    second = second.replace(",Possible,", ",Bogus,").replace("_Possible", "_Bogus")
    second = second.replace("_Impossible", "_Bogus")
    metadata.write_text("\n".join([header, first, "", second, *rest]) + "\n")  # line 4
    with pytest.raises(BenchmarkDataError, match=rf"{metadata}, line 4: unknown type"):
        read_metadata(root, "Main")
    outside = tmp_path / "x.mp4"
    outside.write_bytes((root / "Main" / "Videos").glob("*.mp4").__next__().read_bytes())
    rows = list(csv.DictReader(open(root / "HeldOut" / "metadata.csv")))
    for file_name in ("../../x.mp4", str(outside)):
        rows[1]["file_name"] = file_name
        with open(root / "HeldOut" / "metadata.csv", "w", newline="") as stream:
            writer = csv.DictWriter(stream, ["file_name"])
            writer.writeheader()
            writer.writerows(rows)
        with pytest.raises(BenchmarkDataError) as raised:
            read_metadata(root, "HeldOut", labelled=False)
        assert str(raised.value).startswith(
            f"{root / 'HeldOut' / 'metadata.csv'}, line 3: file_name {file_name!r} names "
            f"{outside}, outside the dataset root {root}"
        )


def test_a_value_error_in_the_users_callable_names_it_and_debug_shows_its_traceback(
    workdir, capsys, monkeypatch
):
    line = refused(capsys, _test(*CALLABLE, "test_clear_answers.raises_value_error"))
    assert line == (
        "error: test_clear_answers.raises_value_error raised ValueError: my model cannot take "
        f"6 frames ({DEBUG_VARIABLE}=1 or --debug shows its traceback)"
    )
    monkeypatch.setenv(DEBUG_VARIABLE, "1")
    with pytest.raises(ValueError) as raised:
        main(_test(*CALLABLE, "test_clear_answers.raises_value_error"))
    assert raised.value.__cause__.__traceback__.tb_frame is not None  # the callable's own
    assert "raises_value_error" in str(raised.value)


def test_an_nn_module_with_trainable_weights_is_refused_naming_requires_grad(workdir, capsys):
    line = refused(capsys, _test(*CALLABLE, "test_clear_answers.frame_change"))
    assert "untrained weights of CallableModel (2 trainable parameters)" in line
    assert ".requires_grad_(False)" in line


def test_wrong_shaped_expected_frames_are_named_and_the_report_is_written(workdir):
    with pytest.warns(UserWarning) as warned:
        main(
            _test(
                "--model",
                "test_clear_answers.WrongExpectation",
                "--model.init_args.function",
                "test_clear_answers.brightness",
            )
        )
    messages = [str(w.message) for w in warned]
    assert any(
        "WrongExpectation.expected_frames returned shape (" in m
        and "expected a tensor [B, T, 3, H, W] = [" in m
        and "predictions_<concept>.png not written" in m
        for m in messages
    ), messages
    [report] = Path("runs/tiny").glob("*/voe_report")
    assert (report / "summary.json").is_file() and not list(report.glob("predictions_*.png"))


# ----------------------------------------------------------------------------- files and signals
def test_generate_leaves_a_running_writers_temporary_files(tmp_path):
    ended = subprocess.Popen(["true"])
    ended.wait()
    host = socket.gethostname()
    shard = tmp_path / "shard-00000.voe"
    running = tmp_path / f".{shard.name}.{host}.{os.getpid()}.abc.tmp"  # a writer at work
    stale = tmp_path / f".{shard.name}.{host}.{ended.pid}.def.tmp"  # a killed writer's
    for path in (running, stale):
        path.write_bytes(b"partial")
    generation._remove_stale_temporaries(shard)
    assert running.exists() and not stale.exists()


def test_a_checkpoint_on_a_full_disk_leaves_no_truncated_file(tmp_path, monkeypatch):
    trainer = L.Trainer(logger=False, enable_checkpointing=False, enable_progress_bar=False)
    InterruptCheckpoint().setup(trainer, None, "fit")
    assert isinstance(trainer.strategy.checkpoint_io, WholeCheckpointIO)
    folder = tmp_path / "checkpoints"
    previous = folder / "last.ckpt"
    io = trainer.strategy.checkpoint_io
    io.save_checkpoint({"global_step": 1}, previous)
    write = files._write_bytes

    def full_disk(file, data):  # half the checkpoint fits
        write(file, data[: len(data) // 2])
        file.flush()
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(files, "_write_bytes", full_disk)
    for name in ("epoch=0-step=2.ckpt", "last.ckpt"):
        with pytest.raises(OSError) as raised:
            io.save_checkpoint({"global_step": 2, "state": torch.zeros(4096)}, folder / name)
        assert raised.value.errno == errno.ENOSPC
        assert f"cannot write {folder / name}: No space left on device" in str(raised.value)
    assert sorted(path.name for path in folder.iterdir()) == ["last.ckpt"]  # no temporary
    assert torch.load(previous, weights_only=True) == {"global_step": 1}


def test_sigterm_during_test_exits_at_once_with_one_line(workdir, capsys):
    config = workdir / "sigterm.yaml"
    config.write_text(
        yaml.safe_dump(
            {"trainer": {"callbacks+": [{"class_path": "test_clear_answers.SigtermAtTestBatch"}]}}
        )
    )
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(SystemExit) as raised:
        main(_test("--config", str(config), *CALLABLE, "test_clear_answers.brightness"))
    assert raised.value.code == 128 + signal.SIGTERM
    assert "test stopped by SIGTERM; nothing written" in capsys.readouterr().err
    assert not list(Path("runs").glob("**/voe_report/summary.json"))
    assert signal.getsignal(signal.SIGTERM) == before


def test_a_read_only_run_folder_of_a_checkpoint_names_what_would_help(tmp_path, monkeypatch):
    run = tmp_path / "runs" / "tiny" / "version_0"
    (run / "checkpoints").mkdir(parents=True)
    checkpoint = run / "checkpoints" / "last.ckpt"
    config = Namespace(
        ckpt_path=str(checkpoint),
        trainer=Namespace(
            logger=Namespace(
                init_args=Namespace(
                    save_dir=str(tmp_path / "runs"), name="tiny", version="version_0"
                )
            )
        ),
    )
    monkeypatch.setattr(os, "access", lambda path, mode: Path(path) != run)  # read-only run
    with pytest.raises(PermissionError) as raised:
        run_folders.check_run_folder(config)
    message = str(raised.value)
    assert f"whatever save_dir is: make {run} writable" in message
    assert f"copy the checkpoint out of checkpoints/ (cp {checkpoint} model.ckpt" in message
    config.ckpt_path = None  # no checkpoint: save_dir is where the run goes
    with pytest.raises(PermissionError, match="choose another trainer.logger.init_args.save_dir"):
        run_folders.check_run_folder(config)


def test_a_folder_as_a_figure_or_a_file_as_the_audit_folder_is_one_line(tmp_path, capsys):
    runs = curve_runs(tmp_path)
    folder = tmp_path / "figures"
    folder.mkdir()
    arguments = ["analyze", "curves", "--runs", json.dumps([str(runs[0][1])]), "--out"]
    line = refused(capsys, [*arguments, str(folder)])
    assert line == (
        f"error: cannot write a figure as {folder}: it is a folder, and a figure is one file; "
        f"give a file path, e.g. {folder / 'figure.png'}"
    )
    assert folder.is_dir() and not any(folder.iterdir())
    a_file = tmp_path / "audit.txt"
    a_file.write_text("mine")
    line = refused(capsys, ["audit", "--root", str(tmp_path), "--out", str(a_file)])
    assert line.startswith(f"error: --out {a_file} is a file; it is a folder the audit writes")
    assert a_file.read_text() == "mine"
