"""Nothing silently wrong: a test without a trained checkpoint is refused, last/best
name a real run, reports never mix or keep stale files and say what they were made from,
preemption saves, concurrent generate runs keep each other's concepts, a corrupt pairs.csv is
named, and a bad argument is one line. docs/reliability.md lists each case."""

import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import lightning as L
import pytest
import torch
import yaml
from helpers import ALPHA, pair_results, refused
from helpers.locations import REPO, TINY_CONFIG
from helpers.runs import RESUME_TRAINED, copy_of

from voe_lightning import specs
from voe_lightning.cli import main
from voe_lightning.data import store
from voe_lightning.data.store import manifest
from voe_lightning.model.base import SurpriseModel
from voe_lightning.report import ReportInputs, write_report
from voe_lightning.report.pairs import PairResults
from voe_lightning.runs import report_folder
from voe_lightning.scenes.camera import VideoOptions

CONFIGS = REPO / "configs"


class MeanBrightness(SurpriseModel):
    """A physics-blind model without parameters: a frame's surprise is its mean brightness."""

    def surprise(self, frames, mask=None, camera=None, objects=None):
        return specs.to_model_input(frames).mean(dim=(2, 3, 4))

    def expected_frames(self, frames, mask=None, camera=None, objects=None):
        return specs.to_model_input(frames)

    def trajectories(self, frames, mask=None, camera=None, objects=None):
        return {"colour": specs.to_model_input(frames).mean(dim=(3, 4))}  # [B, T, 3]


class SignalAtStep(L.Callback):
    """Sends this process ``signal_name`` when training reaches ``step``, as a preemption."""

    def __init__(self, step: int, signal_name: str):
        self.step, self.signal_name = step, signal_name

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        if trainer.global_step == self.step:
            os.kill(os.getpid(), signal.Signals[self.signal_name])


# ----------------------------------------------------------------------------- 1: checkpoints
@pytest.mark.parametrize(
    "arguments",
    [
        ["test", "--config", TINY_CONFIG],
        [
            "predict",
            "--config",
            str(CONFIGS / "intphys_test.yaml"),
            "--data.init_args.root",
            "nowhere",
        ],
    ],
)
def test_a_trainable_model_without_checkpoint_is_refused_naming_the_fix(workdir, capsys, arguments):
    line = refused(capsys, arguments)
    assert "untrained weights of VRNNLRUModel" in line and "--ckpt_path" in line
    assert not (workdir / "data").exists() and not list(workdir.rglob("voe_report"))


def test_a_model_without_parameters_needs_no_checkpoint(workdir):
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--model",
            "test_refusals_and_whole_reports.MeanBrightness",
        ]
    )
    [report] = workdir.rglob("voe_report")
    source = json.loads((report / "summary.json").read_text())["source"]
    assert source["checkpoint"] is None and source["global_step"] is None
    assert source["concepts"] == ["object_persistence"] and source["data_root"] == "data/tiny"


def test_last_is_the_newest_run_and_the_report_names_what_it_was_made_from(
    workdir, trained, capsys
):
    older = copy_of(trained, workdir)
    newer = older.parent / "version_1"
    shutil.copytree(older, newer)
    os.utime(newer / "checkpoints" / "last.ckpt", (time.time() + 5, time.time() + 5))
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--trainer.logger.init_args.name",
            "trained",
            "--ckpt_path",
            "last",
        ]
    )
    assert f"--ckpt_path last: {Path('runs/trained/version_1/checkpoints/last.ckpt')} (step 1)" in (
        capsys.readouterr().out
    )
    assert not (older / "voe_report").exists()
    source = json.loads((newer / "voe_report" / "summary.json").read_text())["source"]
    assert source == {
        "config": str(Path("runs/trained/version_1/test_config.yaml")),
        "checkpoint": str(Path("runs/trained/version_1/checkpoints/last.ckpt")),
        "global_step": 1,
        "datamodule": "voe_lightning.datamodules.voe.ConceptDataModule",
        "data_root": "data/tiny",
        "seed_offset": 0,
        "probe_root": "data/tiny",
        "probe_split": "test",
        "concepts": ["object_persistence"],
    }
    # fit --ckpt_path last resumes that run (Lightning alone would start again from step 0).
    cli = main(RESUME_TRAINED)
    assert cli.trainer.global_step == 2
    assert sorted(path.name for path in older.parent.iterdir()) == ["version_0", "version_1"]


@pytest.mark.parametrize(
    "word, message",
    [
        (
            "last",
            "no checkpoint of logger name 'nothing': looked for "
            f"{Path('runs/nothing/*/checkpoints/last.ckpt')}",
        ),
        ("best", "monitor no metric"),
    ],
)
def test_last_or_best_without_such_a_checkpoint_is_refused(workdir, trained, capsys, word, message):
    copy_of(trained, workdir)
    name = "nothing" if word == "last" else "trained"
    line = refused(
        capsys,
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--ckpt_path",
            word,
            "--trainer.logger.init_args.name",
            name,
        ],
    )
    assert message in line
    assert not (workdir / "data").exists()


def test_a_directory_as_checkpoint_is_named_as_one(workdir, trained, capsys):
    run = copy_of(trained, workdir)
    line = refused(capsys, ["test", "--config", TINY_CONFIG, "--ckpt_path", str(run)])
    assert f"--ckpt_path {run} is a directory, not a checkpoint file" in line
    assert str(run / "checkpoints" / "last.ckpt") in line
    assert "does not exist" not in line


# ----------------------------------------------------------------------------- 2, 3: folders
@pytest.mark.slow
def test_a_retest_on_another_concept_gets_its_own_folder_and_no_stale_files(workdir, trained):
    run = copy_of(trained, workdir)
    checkpoint = str(run / "checkpoints" / "last.ckpt")
    main(["test", "--config", TINY_CONFIG, "--ckpt_path", checkpoint])
    own = run / "voe_report"
    (own / "stale.png").write_bytes(b"from an earlier report")
    main(["test", "--config", TINY_CONFIG, "--ckpt_path", checkpoint])
    assert not (own / "stale.png").exists(), "a rewritten report keeps no earlier file"
    own_summary = (own / "summary.json").read_text()
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--ckpt_path",
            checkpoint,
            "--data.init_args.concept",
            "continuity",
        ]
    )
    assert (own / "summary.json").read_text() == own_summary
    [other] = [path for path in run.glob("concepts_continuity-*/voe_report")]
    source = json.loads((other / "summary.json").read_text())["source"]
    assert source["concepts"] == ["continuity"]
    assert not list(other.glob("*object_persistence*"))
    assert not list(run.glob(".voe_report*")) and not list(other.parent.glob(".voe_report*"))


@pytest.mark.parametrize(
    "first, second", [("alt/one", "alt_one"), ("a/b", "/a/b"), ("../x", "x"), ("data/x", "data/x/")]
)
def test_two_data_roots_never_share_a_report_folder(tmp_path, monkeypatch, first, second):
    monkeypatch.chdir(tmp_path)
    checkpoint = tmp_path / "runs" / "r" / "version_0" / "checkpoints" / "last.ckpt"
    folders = [
        report_folder(checkpoint, root, None, None, "data/trained", None)
        for root in (first, second)
    ]
    same = Path(first).resolve() == Path(second).resolve()
    assert (folders[0] == folders[1]) == same
    assert report_folder(checkpoint, "data/trained", ["a"], None, "data/trained", ["a"]) is None


# ----------------------------------------------------------------------------- 4: preemption
@pytest.mark.parametrize("signal_name, code", [("SIGTERM", 143), ("SIGINT", 130)])
def test_a_signal_during_fit_saves_a_resumable_checkpoint_and_exits_non_zero(
    workdir, capsys, signal_name, code
):
    config = workdir / "signal.yaml"
    config.write_text(
        yaml.safe_dump(
            {
                "trainer": {
                    "callbacks+": [
                        {
                            "class_path": "test_refusals_and_whole_reports.SignalAtStep",
                            "init_args": {"step": 3, "signal_name": signal_name},
                        }
                    ]
                }
            }
        )
    )
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN in a job started with & or nohup
    with pytest.raises(SystemExit) as raised:
        main(["fit", "--config", TINY_CONFIG, "--config", str(config), "--trainer.max_steps", "6"])
    assert raised.value.code == code
    checkpoint = Path("runs/tiny/version_0/checkpoints/last.ckpt")
    assert (
        f"fit stopped by {signal_name} at step 3; saved a resumable checkpoint {checkpoint}"
        in capsys.readouterr().err
    )
    assert torch.load(checkpoint, weights_only=True)["global_step"] == 3
    assert signal.getsignal(signal.SIGINT) is before  # the handler the fit found, put back
    cli = main(["fit", "--config", TINY_CONFIG, "--trainer.max_steps", "6", "--ckpt_path", "last"])
    assert cli.trainer.global_step == 6
    assert not (workdir / "runs" / "tiny" / "version_1").exists()


# ----------------------------------------------------------------------------- 5: manifest
def test_concurrent_generate_runs_for_two_concepts_keep_both_in_the_manifest(tmp_path, monkeypatch):
    """Each run reads the manifest, pauses (as rendering would), then writes it back."""
    read = store.read_manifest

    def slow_read(root):
        manifest = read(root)
        time.sleep(0.3)
        return manifest

    monkeypatch.setattr(manifest, "read_manifest", slow_read)
    video = VideoOptions(num_frames=8, height=32, width=32)
    entries = {
        concept: store.plan_generation(
            tmp_path, [concept], 2, None, 1, 1, 1, 4, 8, 32, 32, 0
        ).entries[concept]
        for concept in ("continuity", "containment")
    }
    runs = [
        threading.Thread(
            target=manifest.reconcile_manifest,
            args=(tmp_path, video, 4, {concept: entry}, False),
        )
        for concept, entry in entries.items()
    ]
    for run in runs:
        run.start()
    for run in runs:
        run.join()
    assert set(read(tmp_path)["concepts"]) == {"continuity", "containment"}


# ----------------------------------------------------------------------------- 6: report files
@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda text: text[:-4] + "\n", "its SHA-256 is not the one .*summary.json recorded"),
        (lambda text: "\n".join(text.splitlines()[:-1]) + "\n", "holds 3 pairs"),  # a row lost
        (lambda text: text[: len(text) // 2], "no value for"),  # cut mid-row
        (lambda text: text.replace(",2,", ",two,", 1), "manipulation_frame is 'two', not a number"),
    ],
)
def test_a_damaged_pairs_csv_is_named_as_corrupt(tmp_path, damage, message):
    write_report(ReportInputs(pair_results(), alpha=ALPHA, bootstrap=10), tmp_path, echo=False)
    pairs = tmp_path / "voe_report" / "pairs.csv"
    assert len(PairResults.from_csv(pairs)) == 4
    pairs.write_text(damage(pairs.read_text()))
    with pytest.raises(ValueError, match=rf"{pairs} is corrupt .*{message}"):
        PairResults.from_csv(pairs)


def test_an_interrupted_report_leaves_the_previous_one_whole(tmp_path, monkeypatch):
    write_report(ReportInputs(pair_results(), alpha=ALPHA, bootstrap=10), tmp_path, echo=False)
    before = {path.name: path.read_bytes() for path in (tmp_path / "voe_report").iterdir()}

    def fail(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("voe_lightning.report.write_figures", fail)
    with pytest.raises(OSError):
        write_report(ReportInputs(pair_results(6), alpha=ALPHA, bootstrap=10), tmp_path, echo=False)
    after = {path.name: path.read_bytes() for path in (tmp_path / "voe_report").iterdir()}
    assert after == before
    assert [path.name for path in tmp_path.iterdir()] == ["voe_report"]


# ----------------------------------------------------------------------------- one-line errors
@pytest.mark.parametrize(
    "arguments, message",
    [
        (
            ["--data.init_args.test_pairs", "0"],
            "test_pairs must be an integer of at least 1, got 0",
        ),
        (["--ckpt_path", "missing.ckpt"], "--ckpt_path 'missing.ckpt' does not exist"),
    ],
)
def test_a_bad_argument_is_one_line_and_debug_shows_the_traceback(
    workdir, capsys, arguments, message
):
    assert message in refused(capsys, ["fit", "--config", TINY_CONFIG, *arguments])
    with pytest.raises((ValueError, OSError)):
        main(["fit", "--config", TINY_CONFIG, *arguments, "--debug"])
    assert not (workdir / "data").exists()


# ----------------------------------------------------------------------------- cross-checks
@pytest.mark.parametrize(
    "arguments, message",
    [
        (
            ["--data.init_args.batch_size", "64"],
            "data.init_args.batch_size 64 is larger than the 8 training clips",
        ),
        (
            ["--data.init_args.height", "48"],
            "model.init_args.image_size [32, 32] differs from the data's height x width 48 x 32",
        ),
        (
            [
                "--model",
                "voe_lightning.model.ObjectStateModel",
                "--model.init_args.frame_size",
                "[64, 64]",
            ],
            "model.init_args.frame_size [64, 64] differs from the data's height x width 32 x 32",
        ),
        (["--trainer.max_steps", "-2"], "trainer.max_steps -2: give a number of steps >= 0"),
    ],
)
def test_arguments_that_contradict_each_other_are_refused_before_rendering(
    workdir, capsys, arguments, message
):
    assert message in refused(capsys, ["fit", "--config", TINY_CONFIG, *arguments])
    assert not (workdir / "data").exists()


def test_a_fit_that_would_never_validate_says_so(workdir):
    with pytest.warns(
        UserWarning,
        match="val_check_interval 5 is larger than trainer.max_steps 1: no validation will run",
    ):
        main(
            [
                "fit",
                "--config",
                TINY_CONFIG,
                "--trainer.max_steps",
                "1",
                "--trainer.val_check_interval",
                "5",
            ]
        )


def test_a_truncated_summary_json_is_named(tmp_path, capsys):
    write_report(ReportInputs(pair_results(), alpha=ALPHA, bootstrap=10), tmp_path, echo=False)
    summary = tmp_path / "voe_report" / "summary.json"
    summary.write_text(summary.read_text()[:100])
    line = refused(capsys, ["analyze", "compare", "--runs", json.dumps([str(tmp_path)])])
    assert f"{summary} is corrupt (truncated?)" in line


def _retired(checkpoint: Path, workdir: Path) -> Path:
    """``checkpoint`` with a model argument VRNNLRUModel does not take, as an older version's."""
    stored = torch.load(checkpoint, weights_only=True)
    stored["hyper_parameters"]["retired_argument"] = 3
    torch.save(stored, workdir / "old.ckpt")
    return workdir / "old.ckpt"


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["--config", "broken.yaml"], "--config broken.yaml is not valid YAML at line 3, column 1"),
        (
            ["--trainer.logger.init_args.name", "n" * 300],
            "is 300 bytes long; a folder name may have at most 255",
        ),
        (
            ["--trainer.logger.init_args.save_dir", "a_file/runs"],
            f"cannot write the run folder {Path('a_file/runs/tiny')}: a_file is not a writable folder",
        ),
        (
            ["--data.init_args.root", "a_file"],
            "data.init_args.root a_file is a file, not a dataset folder",
        ),
    ],
)
def test_a_bad_file_or_folder_is_named_in_one_line_before_any_work(
    workdir, capsys, arguments, message
):
    (workdir / "broken.yaml").write_text("trainer:\n  max_steps: [1\n")
    (workdir / "a_file").write_text("not a folder")
    assert message in refused(capsys, ["fit", "--config", TINY_CONFIG, *arguments])
    assert not (workdir / "data").exists()


def test_a_checkpoint_argument_the_model_no_longer_takes_is_named(workdir, trained, capsys):
    old = _retired(trained / "checkpoints" / "last.ckpt", workdir)
    line = refused(capsys, ["test", "--config", TINY_CONFIG, "--ckpt_path", str(old)])
    assert f"{old} holds model arguments VRNNLRUModel no longer takes: retired_argument" in line


def test_predict_with_a_datamodule_that_cannot_predict_is_one_line(workdir, trained, capsys):
    line = refused(
        capsys,
        [
            "predict",
            "--config",
            TINY_CONFIG,
            "--ckpt_path",
            str(trained / "checkpoints" / "last.ckpt"),
        ],
    )
    assert "voe_lightning.datamodules.ConceptDataModule has none" in line
    assert not (workdir / "data").exists()


def test_a_shard_too_large_for_memory_is_warned_of(tmp_path):
    with pytest.warns(
        UserWarning,
        match=r"4096 x 4096 x 15 frames with shard_size 100 hold "
        r"about 187.5 GiB per shard",
    ):
        store.plan_generation(tmp_path, ["continuity"], 1, None, 1, 1, 0, 100, 15, 4096, 4096, 0)


def test_generate_of_one_frame_videos_is_one_line_naming_num_frames(tmp_path, capsys):
    line = refused(capsys, ["generate", "--root", str(tmp_path / "data"), "--num_frames", "1"])
    assert "num_frames must be an integer of at least 2" in line
    assert not (tmp_path / "data").exists()


def test_a_setting_a_scene_cannot_render_is_one_line_before_anything_renders(tmp_path, capsys):
    """Solidity's probes need a frame 1 to 1.6 s in with two after it (num_frames >= 5 over
    3 s): generate says so in one line before rendering any shard, of solidity or of a concept
    listed before it."""
    line = refused(
        capsys,
        [
            "generate",
            "--root",
            str(tmp_path),
            "--concepts",
            "[containment, solidity]",
            "--num_frames",
            "4",
            "--height",
            "32",
            "--width",
            "32",
            "--train_examples",
            "1",
            "--val_pairs",
            "1",
            "--test_pairs",
            "1",
            "--generalization_pairs",
            "0",
            "--workers",
            "1",
            "--progress",
            "false",
        ],
    )
    assert "use num_frames >= 5" in line
    assert not list(tmp_path.rglob("*.voe"))  # no shard of either concept rendered


def test_a_checkpoint_retested_on_fresh_probes_says_where_and_keeps_the_training_store(
    workdir, trained, capsys
):
    """Issue 48 part 5: ``--data.init_args.seed_offset N`` generates the test probes into
    data/tiny/seed_offset_<N> (never the training store), and the report, in a folder of its
    own, records the offset in summary.json and summary.md's first line."""
    run = copy_of(trained, workdir)
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--ckpt_path",
            str(run / "checkpoints" / "last.ckpt"),
            "--data.init_args.seed_offset",
            "1000",
        ]
    )
    fresh = Path("data/tiny/seed_offset_1000")
    assert f"generating the test split of object_persistence under {fresh}" in (
        capsys.readouterr().out
    )
    assert sorted(path.name for path in Path("data/tiny").iterdir()) == [fresh.name]
    assert not (run / "voe_report").exists()  # the place of the run's own report
    [report] = [path for path in run.rglob("voe_report") if path.parent != run]
    assert report.parent.name.startswith("data_data_tiny_seed_offset_1000-")
    summary = json.loads((report / "summary.json").read_text())
    assert summary["source"]["seed_offset"] == 1000
    assert summary["source"]["probe_root"] == str(fresh)
    assert (report / "summary.md").read_text().splitlines()[0] == (
        f"Tested: checkpoint {run / 'checkpoints' / 'last.ckpt'} (step 1); the probes of "
        f"{fresh} (seed offset 1000)."
    )
    seeds = PairResults.from_csv(report / "pairs.csv").seed
    assert set(seeds.tolist()) == {2_000_001_000 + k for k in range(3)}


def test_a_run_saved_before_an_argument_existed_resumes_without_it(tmp_path):
    """A run's record (config.yaml) from before ``seed_offset`` is compared on what it holds:
    the new argument is no difference, another value of an old one still is."""
    from voe_lightning.runs import record_differences

    saved = tmp_path / "config.yaml"
    saved.write_text(yaml.safe_dump({"data": {"init_args": {"root": "data/tiny"}}}))
    given = {"data": {"init_args": {"root": "data/tiny", "seed_offset": 0}}}
    assert record_differences(saved, given) == []
    given["data"]["init_args"]["root"] = "data/other"
    assert record_differences(saved, given) == [
        "data.init_args.root: the run trained with 'data/tiny', given 'data/other'"
    ]
