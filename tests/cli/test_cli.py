"""`python -m voe_lightning fit|test` end to end through main([...]) with a tiny config, and the
refusals that must happen before any work starts."""

import csv
import json
import re
import subprocess
import sys
import warnings
from pathlib import Path

import nbformat
import pytest
import torch
import yaml
from helpers import refused
from helpers.locations import REPO, TINY_CONFIG
from helpers.runs import copy_of
from nbclient import NotebookClient
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from voe_lightning.analysis import latent_code
from voe_lightning.cli import main
from voe_lightning.data.store import collate, open_split
from voe_lightning.model import VRNNLRUModel
from voe_lightning.model.object_centric.model import SURPRISES
from voe_lightning.specs import to_model_input


def _tags(run_dir: Path, kind: str = "scalars") -> set[str]:
    accumulator = EventAccumulator(str(run_dir))
    accumulator.Reload()
    return set(accumulator.Tags()[kind])


@pytest.mark.slow
def test_fit_then_test_writes_curves_checkpoint_and_report(workdir):
    main(["fit", "--config", TINY_CONFIG])
    run = workdir / "runs" / "tiny" / "version_0"
    assert (run / "checkpoints" / "last.ckpt").is_file()
    tags = _tags(run)
    for statistic in ("relative_surprise", "t", "p_value", "accuracy"):
        assert f"voe/object_persistence/standard/{statistic}" in tags
        assert f"voe/object_persistence/counterbalanced/{statistic}" in tags
        assert f"voe/object_persistence/pooled/{statistic}" in tags
    assert {"train/loss", "train/reconstruction", "train/kl", "train/prior_regularizer"} <= tags
    assert "expected/object_persistence" in _tags(run, "images")  # input above expectation

    main(["test", "--config", TINY_CONFIG, "--ckpt_path", str(run / "checkpoints" / "last.ckpt")])
    report = run / "voe_report"  # beside the checkpoint's run, not in a new version
    summary = json.loads((report / "summary.json").read_text())["rows"]
    cases = {(row["concept"], row["variant"], row["n"]) for row in summary}
    assert cases == {
        ("object_persistence", "standard", 3),
        ("object_persistence", "counterbalanced", 3),
        ("object_persistence", "pooled", 6),
        ("object_persistence", "quadruplet", 3),
    }  # the test seeds' quadruplets
    for name in ("pairs.csv", "summary.md", "histograms.png", "surprise_per_frame.png"):
        assert (report / name).is_file(), name
    # The cue audit of the same test pairs, beside the model's rows.
    with open(report / "cues.csv", newline="") as handle:
        cue_cases = {(r["concept"], r["variant"], int(r["n"])) for r in csv.DictReader(handle)}
    assert cue_cases == cases
    assert "| object_persistence | **pooled** | 6 |" in (report / "cues.md").read_text()
    assert "- object_persistence: " in (report / "summary.md").read_text()  # the verdict

    # The notebook reproduces the figures from this real run's directory.
    notebook = nbformat.read(REPO / "notebooks" / "voe_report.ipynb", 4)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("VOE_RUN_DIR", str(run))
        patch.delenv("VOE_SWEEP_RESULTS", raising=False)
        NotebookClient(notebook, timeout=180, kernel_name="python3").execute()
    outputs = [out for cell in notebook.cells if cell.cell_type == "code" for out in cell.outputs]
    assert sum("image/png" in out.get("data", {}) for out in outputs) >= 3  # hist, frames, curves
    markdown = "".join(out.get("data", {}).get("text/markdown", "") for out in outputs)
    assert "| object_persistence | standard | 3 |" in markdown


def test_fits_last_screen_fits_80_columns_and_ends_with_the_test_to_run(workdir, capsys):
    """The VOE table's cells never wrap at 80 columns (why a concept shows no VOE is a
    footnote), and fit ends with the exact test command of its run, which runs as printed."""
    main(["fit", "--config", TINY_CONFIG])
    out = capsys.readouterr().out
    table = out[out.index("VOE on validation probes") :]
    lines = table.splitlines()
    cells = table[: table.index("* p < ")].splitlines()  # the footnotes below are plain text
    assert max(len(line.rstrip()) for line in cells) <= 80
    assert re.search(r"^ object_persistence +(VOE|no VOE¹|undecided¹)\s*$", table, re.M)
    assert not re.search(r"^ +(VOE|no VOE)\s*$", table, re.M)  # no verdict cell wrapped alone
    run = Path("runs", "tiny", "version_0")  # where the config's logger puts it, from here
    command = lines[-1].split()
    assert lines[-2] == f"next, the report on the test probes (into {run / 'voe_report'}):"
    assert command[:3] == ["python", "-m", "voe_lightning"]
    main(command[3:])
    assert (run / "voe_report" / "summary.json").is_file()


def test_a_shipped_config_is_given_by_name_and_an_unknown_name_is_refused(workdir, capsys):
    """``--config quickstart`` (and ``overlays/untrained_null``, ``.yaml`` optional) is the
    package's own config wherever it is installed; a name that is neither a file nor shipped is
    one line listing the shipped ones."""
    with pytest.raises(SystemExit):
        main(
            ["fit", "--config", "quickstart", "--config=overlays/untrained_null", "--print_config"]
        )
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["trainer"]["logger"]["init_args"]["name"] == "quickstart"
    assert printed["data"]["init_args"]["generalization"] is False  # the overlay's
    line = refused(capsys, ["fit", "--config", "quickstrat"])
    assert line.startswith("error: --config quickstrat is neither a file nor a config the package")
    assert "learned_states, " in line and "overlays/untrained_null" in line


def test_resume_continues_in_the_same_run(workdir):
    main(["fit", "--config", TINY_CONFIG])
    checkpoint = workdir / "runs" / "tiny" / "version_0" / "checkpoints" / "last.ckpt"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cli = main(
            [
                "fit",
                "--config",
                TINY_CONFIG,
                "--trainer.max_steps",
                "4",
                "--ckpt_path",
                str(checkpoint),
            ]
        )
    assert not [w for w in caught if "resumes in the checkpoint's run" in str(w.message)]
    assert cli.trainer.global_step == 4
    assert not (workdir / "runs" / "tiny" / "version_1").exists()
    # Another logger name cannot move a resumed run: it is named as not used, not dropped silently.
    with pytest.warns(
        UserWarning, match=r"resumes in the checkpoint's run .*tiny.*'elsewhere' is not used"
    ):
        cli = main(
            [
                "fit",
                "--config",
                TINY_CONFIG,
                "--trainer.max_steps",
                "6",
                "--ckpt_path",
                str(checkpoint),
                "--trainer.logger.init_args.name",
                "elsewhere",
            ]
        )
    assert cli.trainer.global_step == 6
    assert not (workdir / "runs" / "elsewhere").exists()


@pytest.mark.parametrize(
    "checkpoint_class,last_step",
    [
        ("lightning.pytorch.callbacks.ModelCheckpoint", 2),  # Lightning: the last scheduled step
        ("voe_lightning.callbacks.FinalStepCheckpoint", 3),  # ours: the step training ended at
    ],
)
def test_last_checkpoint_holds_the_step_training_ended_at(workdir, checkpoint_class, last_step):
    config = yaml.safe_load(Path(TINY_CONFIG).read_text())
    for callback in config["trainer"]["callbacks"]:
        if callback["class_path"].endswith("FinalStepCheckpoint"):
            callback["class_path"] = checkpoint_class
            callback["init_args"] = {"save_last": True, "every_n_train_steps": 2}
    (workdir / "tiny.yaml").write_text(yaml.safe_dump(config))
    main(["fit", "--config", "tiny.yaml", "--trainer.max_steps", "3"])
    checkpoints = workdir / "runs" / "tiny" / "version_0" / "checkpoints"
    assert torch.load(checkpoints / "last.ckpt", weights_only=True)["global_step"] == last_step
    assert [path.name.split("-")[-1] for path in checkpoints.glob("epoch=*")] == [
        f"step={last_step}.ckpt"
    ]


@pytest.mark.parametrize(
    "arguments,message",
    [
        (["--data.concept", "gravity"], "object_persistence"),
        (["--data.init_args.no_such_key", "1"], "no_such_key"),
        (["--ckpt_path", "missing.ckpt"], "missing.ckpt"),
    ],
)
def test_bad_configs_are_refused_before_any_work(workdir, capsys, arguments, message):
    with pytest.raises((SystemExit, FileNotFoundError)) as raised:
        main(["fit", "--config", TINY_CONFIG, *arguments])
    captured = capsys.readouterr()
    assert message in captured.err + captured.out + str(raised.value)
    assert not (workdir / "data").exists(), "no data may be generated for a refused config"


@pytest.mark.slow
def test_module_entry_point_lists_every_subcommand_with_its_summary():
    result = subprocess.run(
        [sys.executable, "-m", "voe_lightning", "--help"],
        capture_output=True,
        text=True,
        check=True,
    )
    for subcommand in (
        "fit",
        "validate",
        "test",
        "predict",
        "generate",
        "audit",
        "check-causality",
        "analyze",
    ):
        assert re.search(rf"^ +{subcommand} +[A-Z]", result.stdout, re.MULTILINE), subcommand


@pytest.mark.parametrize(
    "command,summary",
    [
        (["generate"], "sharded store"),
        (["audit"], "Physics-blind cue scores"),
        (["check-causality"], "causality protocol on generated probe pairs"),
        (["analyze"], "curves, emergence, sweep, sweep-plot, compare"),
        (["analyze", "curves"], "Figure 6"),
        (["analyze", "emergence"], "When each concept's VOE emerges over training"),
        (["analyze", "sweep"], "per training-set size"),
        (["analyze", "sweep-plot"], "Figure 3"),
        (["analyze", "compare"], "verdicts"),
        (["analyze", "calibrate"], "Calibration of the VOE"),
    ],
)
def test_each_command_has_a_help_with_its_summary_and_config(capsys, command, summary):
    with pytest.raises(SystemExit) as raised:
        main([*command, "--help"])
    assert raised.value.code == 0
    printed = capsys.readouterr().out
    assert summary in printed and "--config CONFIG" in printed


def test_test_on_intphys_dev_reports_the_benchmark_metrics(workdir, trained):
    from helpers.intphys import FRAMES, make_intphys

    make_intphys(workdir / "intphys", "dev", labelled=True)
    run = copy_of(trained, workdir)
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--ckpt_path",
            str(run / "checkpoints" / "last.ckpt"),
            "--data",
            "voe_lightning.benchmarks.intphys.IntPhysDataModule",
            "--data.root",
            str(workdir / "intphys"),
            "--data.num_frames",
            "5",
            "--data.height",
            "32",
            "--data.width",
            "32",
            "--data.frames_per_movie",
            str(FRAMES),
        ]
    )
    [report] = run.glob("tiny-*/voe_report")  # the benchmark's own folder in the run
    metrics = json.loads((report / "benchmark_metrics.json").read_text())
    assert metrics, "the IntPhys metrics must be reported"
    assert "relative_error_rate" in json.dumps(metrics)
    summary = json.loads((report / "summary.json").read_text())["rows"]
    assert {row["concept"] for row in summary} <= {"O1_object_permanence", "O2_shape_constancy"}
    # IntPhys has no masks: the cue audit skips foreground_pixels with a note, not a failure.
    assert "foreground_pixels skipped" in (report / "cues.md").read_text()


def test_predict_with_the_intphys_test_config_writes_the_answer_file(workdir):
    from helpers.intphys import FRAMES, make_intphys

    make_intphys(workdir / "intphys", "test", labelled=False)
    main(["fit", "--config", TINY_CONFIG, "--trainer.max_steps", "1"])
    checkpoint = workdir / "runs" / "tiny" / "version_0" / "checkpoints" / "last.ckpt"
    configs = REPO / "configs"
    main(
        [
            "predict",
            "--config",
            str(configs / "intphys_test.yaml"),
            "--ckpt_path",
            str(checkpoint),
            "--data.init_args.root",
            str(workdir / "intphys"),
            "--data.init_args.num_frames",
            "5",
            "--data.init_args.frames_per_movie",
            str(FRAMES),
            "--data.init_args.num_workers",
            "0",
            "--data.init_args.cache_dir",
            "null",
        ]
    )
    lines = (workdir / "answer.txt").read_text().splitlines()
    assert len(lines) == 3 * 4  # three scenes of four movies
    path, score = lines[0].split()
    assert path.startswith("O1/") and 0.0 <= float(score) <= 1.0


@pytest.mark.slow
def test_size_sweep_trains_and_tests_through_the_real_cli(workdir):
    rows = main(
        [
            "analyze",
            "sweep",
            "--lightning_configs",
            json.dumps([TINY_CONFIG]),
            "--sizes",
            "[4, 8]",
            "--eval_sets",
            "2",
            "--pairs_per_set",
            "3",
            "--extra_args",
            '["--data.root=data/size{size}"]',
            "--out",
            "sweep.json",
            "--plot",
            "sweep.png",
        ]
    )
    assert {row["train_size"] for row in rows} == {4, 8}
    assert {row["eval_set"] for row in rows} == {0, 1}
    assert all(row["n"] == 3 for row in rows)
    assert (workdir / "sweep.png").stat().st_size > 0
    assert (workdir / "data" / "size4").is_dir() and (workdir / "data" / "size8").is_dir()


def test_a_checkpoint_of_another_architecture_is_refused_naming_the_difference(workdir):
    # The CLI takes the model's arguments from --ckpt_path; code that builds its own model and
    # restores a checkpoint into it must get a clear error, not a state_dict size mismatch.
    cli = main(["fit", "--config", TINY_CONFIG, "--trainer.max_steps", "1"])
    checkpoint = workdir / "runs" / "tiny" / "version_0" / "checkpoints" / "last.ckpt"
    arguments = {k: v for k, v in cli.model.hparams.items() if not k.startswith("_")}
    other = VRNNLRUModel(**{**arguments, "latent_size": 12})
    with pytest.raises(
        ValueError, match=rf"{checkpoint} was .*\(latent_size: checkpoint 8, config 12\)"
    ):
        cli.trainer.validate(other, datamodule=cli.datamodule, ckpt_path=str(checkpoint))


def test_validate_reports_the_voe_statistics(workdir):
    cli = main(["validate", "--config", TINY_CONFIG])
    metrics = cli.trainer.callback_metrics
    assert "voe/object_persistence/standard/relative_surprise" in metrics
    assert metrics["voe/object_persistence/pooled/n"] == 4  # 2 val pairs per variant


def _alphas(cli) -> dict[str, float]:
    return {type(c).__name__: c.alpha for c in cli.trainer.callbacks if hasattr(c, "alpha")}


def test_the_runs_one_alpha_reaches_every_callback_and_a_second_one_is_refused(workdir):
    """configs/base.yaml's top-level alpha (or --alpha) is every callback's; a callback given
    another alpha of its own is refused, naming both."""
    limit = ["--trainer.limit_val_batches", "0"]  # the callbacks are built, nothing runs
    default = main(["validate", "--config", TINY_CONFIG, *limit])
    assert default.config["validate"]["alpha"] == 0.01
    assert _alphas(default) == {"VOEProbeCallback": 0.01, "VOEReportCallback": 0.01}
    chosen = main(["validate", "--config", TINY_CONFIG, "--alpha", "0.05", *limit])
    assert _alphas(chosen) == {"VOEProbeCallback": 0.05, "VOEReportCallback": 0.05}
    saved = yaml.safe_load(
        (workdir / "runs" / "tiny" / "version_1" / "validate_config.yaml").read_text()
    )
    assert saved["alpha"] == 0.05  # the saved config says which alpha the run used
    second = workdir / "second_alpha.yaml"
    second.write_text(
        "trainer:\n  callbacks+:\n"
        "    - class_path: voe_lightning.callbacks.VOEReportCallback\n"
        "      init_args: {alpha: 0.05}\n"
    )
    with pytest.raises(
        ValueError,
        match=r"VOEReportCallback was given alpha 0.05, the run's "
        r"alpha is 0.01: a run has one significance level",
    ):
        main(["validate", "--debug", "--config", TINY_CONFIG, "--config", str(second), *limit])
    with pytest.raises(ValueError, match=r"alpha must be a significance level in \(0, 1\)"):
        main(["validate", "--debug", "--config", TINY_CONFIG, "--alpha", "2", *limit])


def test_training_does_not_depend_on_how_often_validation_runs(workdir):
    def weights(name, interval):
        cli = main(
            [
                "fit",
                "--config",
                TINY_CONFIG,
                "--trainer.max_steps",
                "6",
                "--trainer.val_check_interval",
                str(interval),
                "--trainer.logger.init_args.name",
                name,
            ]
        )
        return cli.model.state_dict()

    every_two, every_three = weights("a", 2), weights("b", 3)
    assert all(torch.equal(every_two[key], every_three[key]) for key in every_two)


@pytest.mark.parametrize("command", ["test", "predict"])
def test_checkpoints_are_read_with_weights_only(workdir, monkeypatch, command):
    """Issue 10 case 13: every read of a checkpoint (LightningCLI's, the trainer's, our own)
    passes weights_only=True instead of relying on torch's default (False before torch 2.6)."""
    calls = []

    def spy(*args, **kwargs):
        calls.append(kwargs.get("weights_only"))
        return {}  # an empty checkpoint: loading stops soon after

    monkeypatch.setattr(torch, "load", spy)
    checkpoint = workdir / "model.ckpt"
    checkpoint.write_bytes(b"not read")
    with pytest.raises((Exception, SystemExit)):
        main([command, "--config", TINY_CONFIG, "--ckpt_path", str(checkpoint)])
    assert len(calls) >= 2 and all(value is True for value in calls), calls


@pytest.mark.parametrize("subcommand, split", [("test", "test"), ("validate", "val")])
def test_evaluation_generates_only_the_probes_it_needs_and_says_so(
    workdir, trained, capsys, subcommand, split
):
    """Issue 10 case 9: a mistyped --data.init_args.root must not render a whole dataset."""
    run = copy_of(trained, workdir)
    main(
        [
            subcommand,
            "--config",
            TINY_CONFIG,
            "--data.init_args.root",
            "data/tpyo",
            "--trainer.fast_dev_run",
            "1",
            "--ckpt_path",
            str(run / "checkpoints" / "last.ckpt"),
        ]
    )
    generated = {path.name for path in (workdir / "data" / "tpyo" / "object_persistence").iterdir()}
    assert generated == {split}
    assert f"generating the {split} split of object_persistence under data/tpyo" in (
        capsys.readouterr().out
    )


def test_test_of_a_checkpoint_writes_its_report_beside_it(workdir, trained):
    """Issue 10 case 9: the report of `test --ckpt_path X` goes into X's run, whatever the
    config's logger name, and the run's training config.yaml is kept."""
    run = copy_of(trained, workdir)
    training_config = (run / "config.yaml").read_text()
    main(["test", "--config", TINY_CONFIG, "--ckpt_path", str(run / "checkpoints" / "last.ckpt")])
    assert (run / "voe_report" / "summary.json").is_file()
    assert not (workdir / "runs" / "tiny").exists()
    assert (run / "config.yaml").read_text() == training_config
    assert "last.ckpt" in (run / "test_config.yaml").read_text()  # the test's own config


def test_test_reuses_the_runs_saved_config_with_no_flag_repeated(workdir, trained):
    """``test --config <run>/config.yaml --ckpt_path last``-style: the config a run saved
    tests it as trained (its data, model and logger), nothing repeated on the command line."""
    run = copy_of(trained, workdir)
    main(
        [
            "test",
            "--config",
            str(run / "config.yaml"),
            "--ckpt_path",
            str(run / "checkpoints" / "last.ckpt"),
        ]
    )
    summary = json.loads((run / "voe_report" / "summary.json").read_text())
    assert summary["rows"] and {row["concept"] for row in summary["rows"]} == {"object_persistence"}


def test_test_on_other_data_keeps_the_runs_own_report(workdir, trained, capsys):
    """Issue 10 case 9: `test --ckpt_path X` with a mistyped root generates only its probes
    and writes its report beside the run's own, never over it, saying where."""
    run = copy_of(trained, workdir)
    checkpoint = str(run / "checkpoints" / "last.ckpt")
    main(["test", "--config", TINY_CONFIG, "--ckpt_path", checkpoint])
    own = (run / "voe_report" / "summary.json").read_text()
    main(
        [
            "test",
            "--config",
            TINY_CONFIG,
            "--ckpt_path",
            checkpoint,
            "--data.init_args.root",
            "data/tpyo",
        ]
    )
    assert (run / "voe_report" / "summary.json").read_text() == own
    [other] = run.glob("data_data_tpyo-*")
    assert (other / "voe_report" / "summary.json").is_file()
    out = capsys.readouterr().out
    assert f"its logs and report go to {other}, and the run's own voe_report/ is kept" in out


def test_model_arguments_that_differ_from_the_checkpoint_are_refused(workdir, trained):
    """Issue 10 case 10: LightningCLI takes the model's arguments from --ckpt_path, so one the
    user gives that differs would be ignored; it is refused, naming the file and both values."""
    checkpoint = trained / "checkpoints" / "last.ckpt"
    with pytest.raises(ValueError) as raised:
        main(
            [
                "test",
                "--debug",
                "--config",
                TINY_CONFIG,
                "--ckpt_path",
                str(checkpoint),
                "--model.init_args.latent_size",
                "16",
            ]
        )
    assert str(checkpoint) in str(raised.value)
    assert "latent_size: config 16, checkpoint 8" in str(raised.value)
    assert not (workdir / "data").exists(), "refused before any work"


def test_training_only_arguments_may_differ_when_testing_a_checkpoint(workdir, trained):
    """A run fitted with --model.init_args.lr_schedule cosine (say) is tested with its config,
    which says constant: the optimizer's arguments change nothing `test` computes, so they are
    no conflict there (the checkpoint's are used), while `fit` of the checkpoint refuses them."""
    run = copy_of(trained, workdir)
    checkpoint = str(run / "checkpoints" / "last.ckpt")
    training_only = [
        "--model.init_args.learning_rate",
        "0.5",
        "--model.init_args.lr_schedule",
        "cosine",
        "--model.init_args.kl_warmup_steps",
        "7",
        "--model.init_args.kl_free_bits",
        "0.2",
    ]
    with pytest.raises(ValueError, match="lr_schedule: config 'cosine', checkpoint 'constant'"):
        main(["fit", "--debug", "--config", TINY_CONFIG, "--ckpt_path", checkpoint, *training_only])
    main(["test", "--config", TINY_CONFIG, "--ckpt_path", checkpoint, *training_only])
    assert (run / "voe_report" / "summary.json").is_file()
    assert "lr_schedule: constant" in (run / "hparams.yaml").read_text()


@pytest.fixture(scope="module")
def trained_object_centric(tmp_path_factory):
    """A tiny object-centric model fitted with code-space surprise, one step per stage, under
    runs/oc: its config (the tiny one with this model) and its run directory."""
    folder = tmp_path_factory.mktemp("object_centric")
    config = yaml.safe_load(Path(TINY_CONFIG).read_text())
    config["model"] = {
        "class_path": "voe_lightning.model.ObjectCentricModel",
        "init_args": {
            "image_size": [32, 32],
            "num_slots": 4,
            "code_size": 8,
            "encoder_channels": [8, 8],
            "state_size": 16,
            "relation_sizes": [16],
            "node_sizes": [16],
            "relation_size": 16,
            "perception_steps": 1,
        },
    }
    (folder / "oc.yaml").write_text(yaml.safe_dump(config))
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        main(["fit", "--config", "oc.yaml", "--trainer.logger.init_args.name", "oc"])
    return str(folder / "oc.yaml"), folder / "runs" / "oc" / "version_0"


def test_an_evaluation_only_argument_scores_a_checkpoint_otherwise(
    workdir, trained_object_centric, capsys
):
    """A checkpoint trained with code-space surprise is tested with `surprise_space pixels`
    (``EVALUATION_ONLY``: it changes no parameter): the model is built with it, not the
    checkpoint's, scores the decoded frames, says so, and reports into a folder of its own."""
    config, trained_run = trained_object_centric
    run = copy_of(trained_run, workdir)
    cli = main(
        [
            "test",
            "--config",
            config,
            "--ckpt_path",
            str(run / "checkpoints" / "last.ckpt"),
            "--model.init_args.surprise_space",
            "pixels",
        ]
    )
    assert "surprise_space: pixels (trained with codes)" in capsys.readouterr().out
    model = cli.model.eval()
    assert model.hparams.surprise_space == "pixels"
    [report] = run.glob("surprise_space_pixels-*/voe_report")
    summary = json.loads((report / "summary.json").read_text())
    assert summary["video_surprise"] == f"sum over frames of {SURPRISES['squared_error', 'pixels']}"
    assert not (run / "voe_report").exists(), "the run's own report is not this one"
    generator = torch.Generator().manual_seed(0)
    frames = torch.randint(0, 256, (2, 6, 32, 32, 3), dtype=torch.uint8, generator=generator)
    mask = torch.zeros(2, 6, 32, 32, dtype=torch.uint8)
    mask[:, :, 4:12, 4:12], mask[:, :, 18:26, 16:28] = 1, 2
    camera = torch.randn(2, 6, 6, generator=generator)
    surprise = model.surprise(frames, mask, camera)
    error = (model.expected_frames(frames, mask, camera) - to_model_input(frames)).pow(2)
    pixel_error = error.sum(dim=(2, 3, 4))
    pixel_error[:, 0] = 0.0
    torch.testing.assert_close(surprise, pixel_error)
    model.hparams.surprise_space = "codes"  # the same weights scored as trained
    assert not torch.allclose(surprise, model.surprise(frames, mask, camera))


def test_an_evaluation_only_argument_as_trained_changes_nothing(
    workdir, trained_object_centric, capsys
):
    """`surprise_space codes`, the checkpoint's own, is no difference: nothing is announced and
    the report is the run's own."""
    config, trained_run = trained_object_centric
    run = copy_of(trained_run, workdir)
    cli = main(
        [
            "test",
            "--config",
            config,
            "--ckpt_path",
            str(run / "checkpoints" / "last.ckpt"),
            "--model.init_args.surprise_space",
            "codes",
        ]
    )
    out = capsys.readouterr().out
    assert "evaluation-only" not in out and "scored otherwise" not in out
    assert cli.model.hparams.surprise_space == "codes"
    summary = json.loads((run / "voe_report" / "summary.json").read_text())
    assert summary["video_surprise"] == f"sum over frames of {SURPRISES['squared_error', 'codes']}"
    assert not list(run.glob("surprise_space_*"))


def test_other_model_arguments_are_refused_naming_those_evaluation_may_change(
    workdir, trained_object_centric
):
    """Beside an evaluation-only argument, one that is not (``surprise`` shapes the dynamics)
    is still refused, and the message names what evaluating may change; in `fit` of the
    checkpoint an evaluation-only argument is an ordinary one, refused too."""
    config, run = trained_object_centric
    checkpoint = str(run / "checkpoints" / "last.ckpt")
    with pytest.raises(ValueError) as raised:
        main(
            [
                "test",
                "--debug",
                "--config",
                config,
                "--ckpt_path",
                checkpoint,
                "--model.init_args.surprise_space",
                "pixels",
                "--model.init_args.surprise",
                "likelihood",
            ]
        )
    message = str(raised.value)
    assert "surprise: config 'likelihood', checkpoint 'squared_error'" in message
    assert "surprise_space: config" not in message
    assert (
        "take other values of ObjectCentricModel's training-only learning_rate, "
        "perception_steps, code_loss_weight (ignored) and evaluation-only surprise_space "
        "(used instead of the checkpoint's)"
    ) in message
    with pytest.raises(ValueError, match="surprise_space: config 'pixels', checkpoint 'codes'"):
        main(
            [
                "fit",
                "--debug",
                "--config",
                config,
                "--ckpt_path",
                checkpoint,
                "--model.init_args.surprise_space",
                "pixels",
            ]
        )
    assert not (workdir / "data").exists(), "refused before any work"


def test_a_study_config_on_top_of_base_tests_a_checkpoint(workdir, trained):
    """A study config as in configs/ (logger and model sections without class_path, callbacks
    from base.yaml, which the CLI reads first) tests a checkpoint, and a model argument that
    differs from the checkpoint's is still refused."""
    study = yaml.safe_load(Path(TINY_CONFIG).read_text())
    study["trainer"].pop("callbacks")
    study["trainer"]["logger"] = {"init_args": {"name": "study"}}
    study["model"] = {"init_args": {"latent_size": 8}}
    Path("study.yaml").write_text(yaml.safe_dump(study))
    run = copy_of(trained, workdir)
    checkpoint = str(run / "checkpoints" / "last.ckpt")
    with pytest.raises(ValueError, match="latent_size: config 16, checkpoint 8"):
        main(
            [
                "test",
                "--debug",
                "--config",
                "study.yaml",
                "--ckpt_path",
                checkpoint,
                "--model.init_args.latent_size",
                "16",
            ]
        )
    main(["test", "--config", "study.yaml", "--ckpt_path", checkpoint])
    assert (run / "voe_report" / "summary.json").is_file()


def test_a_checkpoint_without_hyperparameters_that_does_not_fit_is_named(workdir, trained):
    """Issue 10 case 10: no hyper_parameters means the config builds the model; weights that do
    not fit it are refused naming the file and what is missing, not torch's mismatch list."""
    checkpoint = torch.load(trained / "checkpoints" / "last.ckpt", weights_only=True)
    del checkpoint["hyper_parameters"]
    stripped = workdir / "stripped.ckpt"
    torch.save(checkpoint, stripped)
    with pytest.raises(ValueError) as raised:
        main(
            [
                "test",
                "--debug",
                "--config",
                TINY_CONFIG,
                "--ckpt_path",
                str(stripped),
                "--model.init_args.latent_size",
                "16",
            ]
        )
    message = str(raised.value)
    assert str(stripped) in message and "no hyper_parameters" in message
    assert "size mismatch" not in message


@pytest.mark.parametrize("kept", [0.02, 0.5])  # torch: `OSError: [Errno 22]`, a zip RuntimeError
def test_a_truncated_checkpoint_is_named(workdir, trained, kept):
    """Issue 10 case 10: torch's errors for a truncated file name no path."""
    data = (trained / "checkpoints" / "last.ckpt").read_bytes()
    truncated = workdir / "truncated.ckpt"
    truncated.write_bytes(data[: int(len(data) * kept)])
    with pytest.raises(ValueError, match=rf"{truncated}.* truncated or corrupt"):
        main(["test", "--debug", "--config", TINY_CONFIG, "--ckpt_path", str(truncated)])
    assert not (workdir / "data").exists(), "refused before any work"


def test_intphys_test_of_a_checkpoint_writes_beside_it_in_the_models_geometry(workdir, trained):
    """Issue 10 case 15: configs/intphys_dev.yaml tests any checkpoint: the report goes into a
    sub-directory of the checkpoint's run (two checkpoints never share one), and the frames
    are sampled and resized as the checkpoint's model was trained (8 frames of 32x32)."""
    from helpers.intphys import FRAMES, make_intphys

    make_intphys(workdir / "intphys", "dev", labelled=True)
    run = copy_of(trained, workdir)
    config = str(REPO / "configs" / "intphys_dev.yaml")
    cli = main(
        [
            "test",
            "--config",
            config,
            "--ckpt_path",
            str(run / "checkpoints" / "last.ckpt"),
            "--data.root",
            str(workdir / "intphys"),
            "--data.frames_per_movie",
            str(FRAMES),
            "--data.num_workers",
            "0",
            "--data.cache_dir",
            "null",
        ]
    )
    [report] = run.glob("intphys_dev-*/voe_report")  # the benchmark's own folder in the run
    assert (report / "benchmark_metrics.json").is_file()
    assert not (run / "voe_report").exists() and not (workdir / "runs" / "intphys_dev").exists()
    video = cli.datamodule.video
    assert (len(video.indices), video.height, video.width) == (8, 32, 32)


def test_analyze_latents_counts_the_latents_that_carry_information(trained, capsys):
    """`analyze latents` reads consistent test videos from the store and tabulates the KL per
    latent of each checkpoint; its numbers are surprise split over latents."""
    checkpoint = trained / "checkpoints" / "last.ckpt"
    root = trained.parents[2] / "data" / "tiny"
    table = main(
        [
            "analyze",
            "latents",
            "--checkpoints",
            f"[one step={checkpoint}]",
            "--root",
            str(root),
            "--pairs",
            "2",
        ]
    )
    assert "| one step |" in capsys.readouterr().out
    row = table.splitlines()[2].split(" | ")
    assert row[-1].endswith("of 8 |")
    model = VRNNLRUModel.load_from_checkpoint(
        checkpoint, map_location="cpu", weights_only=True
    ).eval()
    frames = collate([open_split(root, "object_persistence", "test")[i] for i in range(2)])[
        "consistent", "frames"
    ]
    surprise = model.surprise(frames)
    usage = latent_code.latent_usage(model, frames, threshold=0.0)
    assert float(row[1]) == pytest.approx(surprise.sum(dim=1).mean().item(), abs=0.06)
    assert usage["kl_per_sequence"] == pytest.approx(surprise.sum(dim=1).mean().item(), rel=1e-5)
    assert usage["first_frame"] == pytest.approx(surprise[:, 0].mean().item(), rel=1e-5)
    assert usage["latents_in_use"] == 8  # KL is positive in every latent of a one-step model
    assert latent_code.latent_usage(model, frames, threshold=1e9)["latents_in_use"] == 0
    with pytest.raises(FileNotFoundError, match="no store at nowhere"):
        latent_code.latents([str(checkpoint)], Path("nowhere"))
