"""Nothing silently wrong, causality and outputs: a model that reads frames after t gets no
verdict and a non-zero exit; docs/reliability.md lists each case with its test."""

import errno
import gzip
import json
import os
import re
import shutil
import socket
import struct
import subprocess
from pathlib import Path

import av
import lightning as L
import numpy as np
import pytest
import torch
import yaml
from helpers import ALPHA, pair_results, refused
from helpers.intphys2 import FRAMES, SIZE, frame, make_root
from helpers.locations import TINY_CONFIG
from helpers.runs import RESUME_TRAINED, copy_of, curve_runs
from rich.console import Console
from tfrecord.writer import TFRecordWriter

from voe_lightning.benchmarks.intphys.reader import read_label
from voe_lightning.benchmarks.intphys2.reader import read_metadata
from voe_lightning.benchmarks.metrics import (
    plausibility_from_surprise,
    read_answer_file,
    relative_error_rate,
    score_answers,
    write_answer_file,
)
from voe_lightning.benchmarks.mp4 import ClipSampling, read_video
from voe_lightning.benchmarks.physical_concepts.reader import read_records
from voe_lightning.benchmarks.reader import BenchmarkDataError, FrameSampling
from voe_lightning.callbacks import voe_table
from voe_lightning.cli import NOT_CAUSAL_EXIT, main
from voe_lightning.data.store import files as store_files
from voe_lightning.report import ReportInputs, write_report
from voe_lightning.stats.causality import check_prefix

TINY_STORE = [
    "--num_frames",
    "6",
    "--height",
    "32",
    "--width",
    "32",
    "--train_examples",
    "1",
    "--val_pairs",
    "2",
    "--test_pairs",
    "2",
    "--generalization_pairs",
    "0",
    "--workers",
    "1",
    "--progress",
    "false",
]
CALLABLE = ["--model", "voe_lightning.model.CallableModel", "--model.init_args.function"]


def reads_the_next_frame(frames: torch.Tensor) -> torch.Tensor:
    """Frame t's surprise is frame t + 1's brightness: it reads the future."""
    brightness = frames.float().mean(dim=(2, 3, 4))
    return torch.cat([brightness[:, 1:], brightness[:, -1:]], dim=1)


def brightness(frames: torch.Tensor) -> torch.Tensor:
    """Frame t's surprise is its own brightness: causal."""
    return frames.float().mean(dim=(2, 3, 4))


# ----------------------------------------------------------------------------- 1: causality
def test_a_model_that_reads_the_future_gets_no_verdict_and_a_non_zero_exit(workdir, capsys):
    with pytest.raises(SystemExit) as raised:
        main(
            [
                "test",
                "--config",
                TINY_CONFIG,
                *CALLABLE,
                "test_causal_verdicts_and_whole_outputs.reads_the_next_frame",
            ]
        )
    assert raised.value.code == NOT_CAUSAL_EXIT
    printed = capsys.readouterr()
    assert "causality: the model is not causal" in printed.out  # summary.md as printed
    assert "object_persistence: no verdict: the model reads frames after t" in printed.out
    assert "VOE (rule" not in printed.out and "undecided" not in printed.out
    errors = [text for text in printed.err.splitlines() if text.startswith("error: ")]
    assert len(errors) == 1 and "Traceback" not in printed.err
    assert "test: causality: the model is not causal" in errors[0]
    assert "in 6 of 6 pairs" in errors[0] and ", first at frame " in errors[0]
    assert "--allow_non_causal true" in errors[0]
    [report] = workdir.rglob("voe_report")
    summary = json.loads((report / "summary.json").read_text())
    assert summary["causality"]["causal"] is False
    assert [v["verdict"] for v in summary["verdicts"]] == [
        "no verdict: the model reads frames after t"
    ]
    assert "no verdict: the model reads frames after t" in (report / "summary.md").read_text()
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            *CALLABLE,
            "test_causal_verdicts_and_whole_outputs.reads_the_next_frame",
            "--allow_non_causal",
            "true",
        ]
    )  # exits 0, the verdict still withheld
    assert "(--allow_non_causal)" in capsys.readouterr().err


def test_a_causal_model_passes_the_check_and_keeps_its_verdict(workdir, capsys):
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            *CALLABLE,
            "test_causal_verdicts_and_whole_outputs.brightness",
        ]
    )
    [report] = workdir.rglob("voe_report")
    summary = json.loads((report / "summary.json").read_text())
    assert summary["causality"] == {
        "causal": True,
        "pairs": 6,
        "non_causal_pairs": 0,
        "largest_difference": 0.0,
        "first_frame": None,
        "unchecked_pairs": 0,
    }
    assert "no verdict" not in summary["verdicts"][0]["verdict"]
    assert (
        "identical before each pair's first difference (where the two videos' inputs are) in all 6 pairs"
        in (capsys.readouterr().out)
    )


def test_the_prefix_check_counts_pairs_and_ignores_float_noise_and_later_frames():
    consistent = torch.tensor([[1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, 4.0], [5.0, 5.0, 5.0, 5.0]])
    inconsistent = consistent.clone()
    inconsistent[0, 3] += 9.0  # after manipulation_frame 2: allowed
    inconsistent[1] += torch.tensor([0.0, 1e-6, 0.5, 0.0])  # noise at 1, a difference at 2
    inconsistent[2, 1] = 7.0  # frame 1 is shared only where the videos first differ at 2
    found = check_prefix(consistent, inconsistent, torch.tensor([2, 2, 3]), torch.tensor([3, 3, 2]))
    assert (found.pairs, found.non_causal, found.first_frame) == (3, 2, 1)
    assert found.largest_difference == pytest.approx(2.0)
    assert check_prefix(consistent, consistent, torch.tensor([3, 3, 3])).causal


def test_validation_of_a_model_that_reads_the_future_warns_and_withholds_the_verdict(
    workdir, capsys
):
    with pytest.warns(UserWarning, match="causality: the model is not causal"):
        with pytest.raises(SystemExit) as raised:
            main(
                [
                    "validate",
                    "--config",
                    TINY_CONFIG,
                    *CALLABLE,
                    "test_causal_verdicts_and_whole_outputs.reads_the_next_frame",
                ]
            )
    assert raised.value.code == NOT_CAUSAL_EXIT
    assert "error: validate: causality: the model is not causal" in capsys.readouterr().err
    causality = check_prefix(torch.zeros(2, 3), torch.ones(2, 3), torch.tensor([1, 1]))
    results = {
        ("continuity", "standard"): {
            "relative_surprise": 2.0,
            "t": 9.0,
            "p_value": 1e-4,
            "accuracy": 1.0,
            "n": 9,
        }
    }
    console = Console(width=200, record=True)
    console.print(voe_table(results, "VOE", causality=causality, alpha=ALPHA))
    text = " ".join(console.export_text().split())  # the caption wraps at the table's width
    assert "no verdict: the model reads frames after t" in text and "in 2 of 2 pairs" in text


def test_check_causality_runs_a_users_model_through_the_protocol(capsys):
    check = [
        "check-causality",
        "--concepts",
        "[object_persistence]",
        "--seeds",
        "1",
        "--num_frames",
        "6",
        *CALLABLE,
    ]
    assert main([*check, "test_causal_verdicts_and_whole_outputs.brightness"]) is True
    printed = capsys.readouterr().out
    assert (
        "object_persistence, pairs before their first difference: causal (surprise "
        "identical in all 2 pairs)"
    ) in printed
    assert "object_persistence, videos cut after each frame t: causal" in printed
    line = refused(capsys, [*check, "test_causal_verdicts_and_whole_outputs.reads_the_next_frame"])
    assert (
        "CallableModel is not causal: its surprise at frame t reads later frames in "
        "object_persistence (pairs before their first difference), object_persistence "
        "(videos cut after each frame t)"
    ) in line


# ----------------------------------------------------------------------------- 2: written whole
@pytest.fixture(scope="module")
def tiny_store(tmp_path_factory):
    """A generated store of object persistence and solidity, two pairs per probe split."""
    root = tmp_path_factory.mktemp("store")
    main(
        [
            "generate",
            "--root",
            str(root),
            "--concepts",
            "[object_persistence, solidity]",
            *TINY_STORE,
        ]
    )
    return root


def _disk_full_after(monkeypatch, files: int) -> None:
    """Every write to disk through ``store.files`` after the first ``files`` files fails
    with ENOSPC (a full disk)."""
    written = []

    def write(file, data):
        if len(written) >= files:
            raise OSError(errno.ENOSPC, "No space left on device")
        written.append(file.name)
        file.write(data)

    monkeypatch.setattr(store_files, "_write_bytes", write)


def _contents(folder):
    return {path.name: path.read_bytes() for path in folder.iterdir()}


def test_a_full_disk_during_audit_names_the_file_and_keeps_the_previous_audit(
    tiny_store, tmp_path, monkeypatch, capsys
):
    out = tmp_path / "audit"
    audit = ["audit", "--root", str(tiny_store), "--out", str(out), "--progress", "false"]
    main(audit)
    before = _contents(out)
    assert {"cues.md", "cues.csv", "cues.json"} <= set(before)
    _disk_full_after(monkeypatch, 1)  # the second file of the audit finds the disk full
    line = refused(capsys, [*audit, "--alpha", "0.05"])
    assert "No space left on device" in line and f"cannot write {out}" in line
    assert _contents(out) == before  # every file the previous audit's, no temporary left


def test_a_full_disk_keeps_the_previous_answer_file_whole(tmp_path, monkeypatch):
    path = tmp_path / "answer.txt"
    surprise = {f"O1/a/{movie}": float(movie) for movie in range(1, 5)}
    write_answer_file(path, surprise)
    before = path.read_bytes()
    _disk_full_after(monkeypatch, 0)
    with pytest.raises(OSError, match=f"cannot write {path}: No space left on device"):
        write_answer_file(path, {movie: -value for movie, value in surprise.items()})
    assert path.read_bytes() == before and _contents(tmp_path).keys() == {"answer.txt"}
    assert len(read_answer_file(path)) == 4


# ----------------------------------------------------------------------------- 3: audit verifies
@pytest.mark.parametrize(
    "source, message",
    [
        ("solidity/test", "its concept is 'solidity', expected 'object_persistence'"),
        ("object_persistence/val", "its split is 'val', expected 'test'"),
    ],
)
def test_audit_refuses_a_shard_of_another_concept_or_split(
    tiny_store, tmp_path, capsys, source, message
):
    root = tmp_path / "store"
    shutil.copytree(tiny_store, root)
    shard = root / "object_persistence" / "test" / "shard-00000.voe"
    shutil.copyfile(root / source / "shard-00000.voe", shard)
    line = refused(
        capsys,
        ["audit", "--root", str(root), "--concepts", "[object_persistence]", "--progress", "false"],
    )
    assert f"corrupt shard {shard}: does not belong here: {message}" in line
    assert not (root / "cue_audit").exists()


# ----------------------------------------------------------------------------- 4: a run's record
@pytest.mark.parametrize(
    "argument, value, message",
    [
        ("concept", "continuity", "the run trained with 'object_persistence', given 'continuity'"),
        ("batch_size", "1", "the run trained with 2, given 1"),
    ],
)
def test_a_resumed_fit_on_other_data_is_refused_and_the_record_kept(
    workdir, trained, capsys, argument, value, message
):
    run = copy_of(trained, workdir)
    record = (run / "config.yaml").read_bytes()
    line = refused(capsys, [*RESUME_TRAINED, f"--data.init_args.{argument}", value])
    assert f"resumes the run {run.relative_to(workdir)}, which trained on other data" in line
    assert f"data.init_args.{argument}: {message}" in line
    assert not (workdir / "data").exists()  # refused before any work
    main(RESUME_TRAINED)  # on the run's own data: resumed, its config saved beside the record
    assert (run / "config.yaml").read_bytes() == record
    resumed = yaml.safe_load((run / "config_resumed_step1.yaml").read_text())
    assert resumed["trainer"]["max_steps"] == 2


def test_a_branch_continues_on_other_data_in_a_new_version(workdir, trained, capsys):
    run = copy_of(trained, workdir)
    record = (run / "config.yaml").read_bytes()
    cli = main(
        [
            *RESUME_TRAINED,
            "--branch",
            "true",
            "--data.init_args.concept",
            "continuity",
        ]
    )
    assert cli.trainer.global_step == 2
    branch = run.parent / "version_1"
    assert "fit --branch: continues from" in capsys.readouterr().out
    branched = yaml.safe_load((branch / "config.yaml").read_text())
    assert branched["data"]["init_args"]["concept"] == "continuity"
    assert (run / "config.yaml").read_bytes() == record
    assert (branch / "checkpoints" / "last.ckpt").is_file()


def test_nothing_is_written_through_a_link_out_of_the_run_folder(workdir, trained, capsys):
    run = copy_of(trained, workdir)
    elsewhere = workdir / "elsewhere.txt"
    elsewhere.write_text("someone else's file\n")
    (run / "test_config.yaml").symlink_to(elsewhere)
    main(["test", "--config", TINY_CONFIG, "--ckpt_path", str(run / "checkpoints" / "last.ckpt")])
    assert (run / "test_config.yaml").is_symlink() and (run / "test_config-2.yaml").is_file()
    (run / "config.yaml").unlink()
    (run / "config.yaml").symlink_to(elsewhere)
    line = refused(
        capsys,
        [
            "fit",
            "--config",
            TINY_CONFIG,
            "--trainer.max_steps",
            "1",
            "--trainer.logger.init_args.name",
            "trained",
            "--trainer.logger.init_args.version",
            "version_0",
        ],
    )
    assert f"{run.relative_to(workdir) / 'config.yaml'} is a symbolic link to {elsewhere}" in line
    assert elsewhere.read_text() == "someone else's file\n"


def test_a_retest_keeps_the_earlier_evaluations_config(workdir, trained):
    """validate and test of a run's checkpoint save their config beside the earlier one's
    (``-2``), not over it; the report names the config it was made with."""
    run = copy_of(trained, workdir)
    checkpoint = ["--config", TINY_CONFIG, "--ckpt_path", str(run / "checkpoints" / "last.ckpt")]
    for subcommand in ("validate", "test"):
        main([subcommand, *checkpoint])
        main([subcommand, *checkpoint, "--seed_everything", "7"])
        first, second = (
            yaml.safe_load((run / f"{subcommand}_config{suffix}.yaml").read_text())
            for suffix in ("", "-2")
        )
        assert (first["seed_everything"], second["seed_everything"]) == (0, 7)
    source = json.loads((run / "voe_report" / "summary.json").read_text())["source"]
    assert Path(source["config"]).resolve() == (run / "test_config-2.yaml").resolve()


# ----------------------------------------------------------------------------- 5: bounded inputs
def test_the_official_score_of_a_written_answer_file_is_the_reports(tmp_path):
    """Surprise sums that tie exactly (0 + 4 = 2 + 2, 0 + 6 = 3 + 3) are ties of plausibility
    sums in memory; six decimals (1 + 0.333333 < 0.666667 + 0.666667) made them errors."""
    surprise = {
        "O1/a/1": 0.0,
        "O1/a/2": 4.0,
        "O1/a/3": 2.0,
        "O1/a/4": 2.0,
        "O1/b/1": 0.0,
        "O1/b/2": 6.0,
        "O1/b/3": 3.0,
        "O1/b/4": 3.0,
    }
    labels = {movie: movie.endswith(("/1", "/2")) for movie in surprise}
    possible = [[surprise[f"O1/{s}/{m}"] for m in (1, 2)] for s in "ab"]
    impossible = [[surprise[f"O1/{s}/{m}"] for m in (3, 4)] for s in "ab"]
    path = write_answer_file(tmp_path / "answer.txt", surprise)
    official = score_answers(read_answer_file(path), labels)["O1"]["all"]
    assert official["relative_error_rate"] == relative_error_rate(possible, impossible) == 0.0
    assert (
        official["relative_error_rate_ties_half"]
        == relative_error_rate(possible, impossible, tie_weight=0.5)
        == 0.5
    )
    assert read_answer_file(path) == {
        movie: float(value)
        for movie, value in zip(
            sorted(surprise), plausibility_from_surprise([surprise[m] for m in sorted(surprise)])
        )
    }


def test_an_out_path_is_the_path_written(tmp_path, capsys):
    runs = curve_runs(tmp_path)
    out = tmp_path / "figure"  # no suffix: matplotlib alone would write figure.png
    main(
        [
            "analyze",
            "curves",
            "--runs",
            json.dumps([f"{label}={path}" for label, path in runs]),
            "--out",
            str(out),
        ]
    )
    assert f"wrote {out}\n" in capsys.readouterr().out
    assert out.read_bytes().startswith(b"\x89PNG") and not out.with_suffix(".png").exists()
    line = refused(
        capsys,
        [
            "analyze",
            "curves",
            "--runs",
            json.dumps([str(runs[0][1])]),
            "--out",
            str(tmp_path / "figure.docx"),
        ],
    )
    assert f"cannot write a figure as {tmp_path / 'figure.docx'}: '.docx' is no image" in line


def test_a_yaml_alias_bomb_is_refused_in_one_line(workdir, capsys):
    levels = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    levels += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)]
    (workdir / "bomb.yaml").write_text("\n".join(levels) + "\n")  # 10^9 values, 500 bytes
    line = refused(capsys, ["fit", "--config", "bomb.yaml"])
    assert "--config bomb.yaml expands to more than 100,000 values through its YAML aliases" in line
    assert len(line) < 400


def test_an_error_in_a_dataloader_worker_is_the_same_one_line(tiny_store, tmp_path, capsys):
    """A record whose checksum fails, read by a worker process: the line the main process
    prints (torch re-raises a CorruptShardError, which takes two arguments, as a RuntimeError
    holding the worker's traceback)."""
    root = tmp_path / "store"
    shutil.copytree(tiny_store, root)
    shard = root / "object_persistence" / "test" / "shard-00000.voe"
    data = bytearray(shard.read_bytes())
    data[40] ^= 0xFF  # inside the first record: the index is intact
    shard.write_bytes(bytes(data))
    audit = [
        "audit",
        "--root",
        str(root),
        "--concepts",
        "[object_persistence]",
        "--progress",
        "false",
    ]
    lines = [refused(capsys, [*audit, "--num_workers", workers]) for workers in ("0", "1")]
    assert (
        lines[0] == lines[1] == f"error: corrupt shard {shard}: record 0 checksum mismatch "
        "(rerun generate with this store's settings, or the fit/test using it, whose "
        "prepare_data regenerates bad shards)"
    )


# ----------------------------------------------------------------------------- 6: weak cases
def test_intphys2_metadata_with_a_byte_order_mark_reads_and_a_latin1_byte_is_named(tmp_path):
    root = make_root(tmp_path / "intphys2_tiny")
    folder = shutil.copytree(root, tmp_path / "intphys2")
    metadata = folder / "Main" / "metadata.csv"
    text = metadata.read_text()
    metadata.write_bytes(b"\xef\xbb\xbf" + text.encode())  # as a spreadsheet saves it
    labels = [
        (video.name, video.scene, video.condition, video.is_possible)
        for video in read_metadata(root, "Main")
    ]
    assert [
        (video.name, video.scene, video.condition, video.is_possible)
        for video in read_metadata(folder, "Main")
    ] == labels
    metadata.write_bytes(text.replace("\n", "\ncaf\xe9,", 1).encode("latin-1"))
    with pytest.raises(BenchmarkDataError, match=f"{metadata} is not UTF-8 text: line 2 holds"):
        read_metadata(folder, "Main")


@pytest.mark.parametrize(
    "name, text, read",
    [
        (
            "status.json",
            '{"header": {"is_possible": true,\n "scene": "caf\xe9"}}\n',
            lambda path: read_label(path.parent),
        ),
        ("answer.txt", "O1/a/1 0.5\nO1/caf\xe9/2 0.5\n", read_answer_file),
    ],
)
def test_a_benchmark_text_file_is_read_as_utf8_and_a_latin1_byte_is_named(
    tmp_path, name, text, read
):
    """IntPhys' status.json and answer.txt as metadata.csv: UTF-8 whatever the locale, and a
    byte UTF-8 cannot decode names the file and its line (Python's error names neither)."""
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    if name == "status.json":
        assert read(path) is True
    path.write_bytes(text.encode("latin-1"))
    with pytest.raises(
        BenchmarkDataError,
        match=re.escape(
            f"{path} is not UTF-8 text: line 2 holds the byte 0xe9, which UTF-8 cannot decode"
        ),
    ):
        read(path)


def write_mpeg4(path, frames):
    """An MPEG-4 Part 2 mp4 with its index first (``movflags faststart``, as streamed video is
    saved): cut short, it still opens, and FFmpeg conceals what is missing."""
    with av.open(str(path), "w", options={"movflags": "faststart"}) as container:
        stream = container.add_stream("mpeg4", rate=10)
        stream.width, stream.height, stream.pix_fmt = SIZE, SIZE, "yuv420p"
        for image in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format="rgb24")))
        container.mux(stream.encode())


def test_a_truncated_or_corrupted_intphys2_video_is_refused_naming_it(tmp_path):
    """Every cut in the last third of a small mp4, and bytes overwritten inside its frames:
    FFmpeg flags a cut packet or logs the damage and decodes other frames, which PyAV (its log
    off) scored in silence; each is now a BenchmarkDataError naming the file."""
    intact = tmp_path / "intact.mp4"
    write_mpeg4(intact, [frame(0, "A", t) for t in range(FRAMES)])
    sampling = ClipSampling(FrameSampling((0, 1, 2, 3), SIZE, SIZE))
    assert read_video(intact, sampling).shape == (4, SIZE, SIZE, 3)
    data = intact.read_bytes()
    corrupted = bytearray(data)
    middle = data.index(b"mdat") + (len(data) - data.index(b"mdat")) // 2
    corrupted[middle : middle + 40] = np.random.default_rng(0).bytes(40)
    damaged = {f"cut_{size}": data[:size] for size in range(len(data) * 2 // 3, len(data))}
    damaged["corrupted"] = bytes(corrupted)
    for name, content in damaged.items():
        path = tmp_path / f"{name}.mp4"
        path.write_bytes(content)
        with pytest.raises(BenchmarkDataError, match=re.escape(str(path))) as error:
            read_video(path, sampling)
        assert error.value.reason == "undecodable_video"
        path.unlink()


class PoisonWeights(L.Callback):
    """Makes the model's weights NaN before training step ``step``, as a diverged run."""

    def __init__(self, step: int = 1):
        self.step = step

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        if trainer.global_step == self.step:
            with torch.no_grad():
                for parameter in pl_module.parameters():
                    parameter.fill_(float("nan"))


def test_a_non_finite_loss_is_one_line(workdir, capsys):
    (workdir / "poison.yaml").write_text(
        yaml.safe_dump(
            {
                "trainer": {
                    "callbacks+": [
                        {"class_path": "test_causal_verdicts_and_whole_outputs.PoisonWeights"}
                    ]
                }
            }
        )
    )
    line = refused(capsys, ["fit", "--config", TINY_CONFIG, "--config", "poison.yaml"])
    assert "non-finite loss at global step 1" in line


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["--config", "configs_folder"], "--config configs_folder is a directory, not a YAML file"),
        (
            ["--model", "nonexistent_pkg.Model"],
            "--model nonexistent_pkg.Model cannot be imported (No module named 'nonexistent_pkg')",
        ),
        (
            ["--data", "voe_lightning.datamodules.NoSuchDataModule"],
            "--data voe_lightning.datamodules.NoSuchDataModule cannot be imported",
        ),
    ],
)
def test_a_config_folder_or_a_class_that_cannot_be_imported_is_one_line(
    workdir, capsys, arguments, message
):
    (workdir / "configs_folder").mkdir()
    line = refused(capsys, ["fit", "--config", TINY_CONFIG, *arguments])
    assert message in line and len(line) < 300


@pytest.mark.parametrize("function", ["returns_none", "returns_a_ragged_list"])
def test_a_callable_returning_no_array_is_one_line(workdir, capsys, function):
    line = refused(
        capsys,
        [
            "test",
            "--config",
            TINY_CONFIG,
            *CALLABLE,
            f"test_causal_verdicts_and_whole_outputs.{function}",
        ],
    )
    assert f"test_causal_verdicts_and_whole_outputs.{function} returned a" in line
    assert "that is no array of numbers" in line and "expected surprise [B, T] = [" in line


def returns_none(frames):
    return None


def returns_a_ragged_list(frames):
    return [[0.0] * (index + 1) for index in range(frames.shape[0])]


def test_audit_of_an_empty_split_or_a_manifest_edited_by_hand_is_one_line(
    tiny_store, tmp_path, capsys
):
    audit = ["audit", "--root", str(tiny_store), "--progress", "false"]
    line = refused(capsys, [*audit, "--split", "generalization"])
    assert "the generalization split of" in line and "holds no probe pairs" in line
    root = shutil.copytree(tiny_store, tmp_path / "store")
    manifest = json.loads((root / "manifest.json").read_text())
    del manifest["video"]["num_frames"]  # a default of 15 would blame the intact shards
    (root / "manifest.json").write_text(json.dumps(manifest))
    line = refused(capsys, ["audit", "--root", str(root), "--progress", "false"])
    assert (
        f"{root / 'manifest.json'}: the manifest describes no valid plan (KeyError: "
        "'video.num_frames')" in line
    )


def test_what_a_killed_writer_staged_is_removed_on_the_next_write(tmp_path):
    ended = subprocess.Popen(["true"])
    ended.wait()  # its id no longer runs
    host = socket.gethostname()
    stale = tmp_path / f".voe_report.{host}.{ended.pid}.x1"
    running = tmp_path / f".voe_report.{host}.{os.getpid()}.x2"  # a report being written now
    other_host = tmp_path / f".voe_report.elsewhere-{host}.1.x3"
    for folder in (stale, running, other_host):
        folder.mkdir()
        (folder / "summary.json").write_text("{}")
    write_report(ReportInputs(pair_results(), alpha=ALPHA, bootstrap=10), tmp_path, echo=False)
    assert not stale.exists() and running.exists() and other_host.exists()
    # The same for a file staged by store.write_whole (answer.txt here).
    stale_file = tmp_path / f".answer.txt.{host}.{ended.pid}.y1.tmp"
    running_file = tmp_path / f".answer.txt.{host}.{os.getpid()}.y2.tmp"
    for file in (stale_file, running_file):
        file.write_text("staged")
    write_answer_file(tmp_path / "answer.txt", {f"O1/a/{movie}": movie for movie in range(1, 5)})
    assert not stale_file.exists() and running_file.exists()


def test_a_physical_concepts_record_with_a_huge_length_field_is_named(tmp_path):
    """A length field whose own checksum holds (so the framing looks intact) asking for 2^60
    bytes: named, not a MemoryError."""
    length = struct.pack("<Q", 1 << 60)
    path = tmp_path / "data.tfrecord-00000-of-00001"
    with gzip.open(path, "wb") as stream:
        stream.write(length + TFRecordWriter.masked_crc(length) + b"\0" * 16)
    with pytest.raises(
        BenchmarkDataError,
        match=rf"{path}: record 0: length field "
        r"1,152,921,504,606,846,976 bytes, more than",
    ):
        list(read_records(path))


def test_generate_repairs_an_empty_folder_in_place_of_a_shard(tiny_store, tmp_path):
    root = shutil.copytree(tiny_store, tmp_path / "store")
    shard = root / "solidity" / "val" / "shard-00000.voe"
    intact = shard.read_bytes()
    shard.unlink()
    shard.mkdir()
    with pytest.warns(UserWarning, match=f"{shard}: a folder, not a shard file"):
        main(
            [
                "generate",
                "--root",
                str(root),
                "--concepts",
                "[object_persistence, solidity]",
                *TINY_STORE,
            ]
        )
    assert shard.read_bytes() == intact
