"""Issue 59's confusing answers, each now one line on stderr, ``error: ...``, naming the bad value
and what would be valid: no traceback, no usage block (docs/reliability.md, "One line, not a
traceback or the parser's usage")."""

import pytest
import torch
import yaml
from helpers.locations import REPO, TINY_CONFIG

from voe_lightning import specs
from voe_lightning.cli import main
from voe_lightning.cli.parser_errors import one_line
from voe_lightning.data.store import render
from voe_lightning.model import CallableModel, SurpriseModel
from voe_lightning.scenes import camera

#: A tiny store to generate: one concept, one clip per shard of 8 frames of 32 x 32.
SMALL = [
    "--concepts", "[continuity]", "--train_examples", "2", "--train_controls", "0",
    "--val_pairs", "0", "--test_pairs", "0", "--generalization_pairs", "0",
    "--shard_size", "1", "--workers", "1", "--progress", "false", "--num_frames", "8",
]  # fmt: skip


def only_line(capsys, arguments: list[str], code: int = 2) -> str:
    """The one line a refused command printed on stderr, all it printed there but warnings."""
    with pytest.raises(SystemExit) as raised:
        main(arguments)
    assert raised.value.code == code
    err = capsys.readouterr().err
    assert "Traceback" not in err and "usage:" not in err, err
    lines = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(lines) == 1, err
    assert not [line for line in err.splitlines() if line.startswith(" ")], err
    return lines[0]


class NoTrajectories(SurpriseModel):
    """A model that forgot ``trajectories``."""

    def surprise(self, frames, mask=None, camera=None, objects=None):
        return specs.to_model_input(frames).mean(dim=(2, 3, 4))

    def expected_frames(self, frames, mask=None, camera=None, objects=None):
        return specs.to_model_input(frames)


def meta_surprise(frames):
    return torch.zeros(frames.shape[:2], device="meta")


def sparse_surprise(frames):
    return torch.zeros(frames.shape[:2]).to_sparse()


# ----------------------------------------------------------------------------- raw tracebacks
def test_a_video_too_small_for_any_scene_says_which_sizes_work(workdir, capsys):
    size = ["--height", "1", "--width", "1", "--val_pairs", "1"]  # a probe needs its ball seen
    line = only_line(capsys, ["generate", "--root", "d", *SMALL, *size])
    assert "no valid scene after 50 draws" in line
    assert "a 1 x 1 (height x width) frame is too small or narrow" in line
    assert f"at least {camera.MIN_SIZE} x {camera.MIN_SIZE}" in line


def test_a_frame_larger_than_the_renderer_draws_names_both_sizes(workdir, capsys):
    line = only_line(capsys, ["generate", "--root", "d", *SMALL, "--width", "40000"])
    assert "frames of 64 x 40000 (height x width) are larger than this renderer draws" in line
    assert "pixels a side (GL_MAX_RENDERBUFFER_SIZE)" in line


def test_a_validation_interval_of_zero_is_refused_before_any_work(workdir, capsys):
    arguments = ["fit", "--config", TINY_CONFIG, "--trainer.val_check_interval", "0"]
    line = only_line(capsys, arguments)
    assert "trainer.val_check_interval 0: give a number of training steps >= 1" in line
    assert not (workdir / "data").exists()


@pytest.mark.parametrize(
    "function,message",
    [
        ("meta_surprise", "returned surprise on the meta device, a tensor of shape (2, 3)"),
        ("sparse_surprise", "returned sparse surprise (torch.sparse_coo): return a dense"),
    ],
)
def test_a_callable_returning_meta_or_sparse_surprise_is_refused_naming_it(function, message):
    model = CallableModel(f"test_one_line_errors.{function}")
    with pytest.raises(ValueError, match="^test_one_line_errors") as raised:
        model.surprise(torch.zeros(2, 3, 4, 4, 3, dtype=torch.uint8))
    assert message in str(raised.value)


def test_a_callable_returning_meta_surprise_is_one_line_from_test(workdir, capsys):
    callable_model = ["--model", "voe_lightning.model.CallableModel"]
    function = ["--model.init_args.function", "test_one_line_errors.meta_surprise"]
    line = only_line(capsys, ["test", "--config", TINY_CONFIG, *callable_model, *function])
    assert "error: test_one_line_errors.meta_surprise returned surprise on the meta" in line


@pytest.mark.parametrize(
    "class_path,message",
    [
        ("boom_at_import.Model", "which does not import (RuntimeError: boom as imported)"),
        ("Model", "which does not import (ValueError: Empty module name)"),
        ("os.path", "which is a module, not a subclass of SurpriseModel"),
        ("test_one_line_errors.meta_surprise", "which is a function, not a subclass"),
    ],
)
def test_a_checkpoint_naming_a_class_that_does_not_import_is_one_line(
    workdir, capsys, monkeypatch, class_path, message
):
    (workdir / "boom_at_import.py").write_text("raise RuntimeError('boom as imported')\n")
    monkeypatch.syspath_prepend(str(workdir))
    torch.save({"hyper_parameters": {"_class_path": class_path}, "global_step": 1}, "x.ckpt")
    line = only_line(capsys, ["test", "--config", TINY_CONFIG, "--ckpt_path", "x.ckpt"])
    assert f"x.ckpt names its model class {class_path}, {message}" in line


def test_ctrl_c_during_generate_is_one_line_and_a_rerun_resumes(workdir, capsys, monkeypatch):
    render_record, rendered = render.render_record, []

    def interrupted_at_the_second_clip(*arguments, **options):
        if rendered:
            raise KeyboardInterrupt
        rendered.append(arguments)
        return render_record(*arguments, **options)

    monkeypatch.setattr(render, "render_record", interrupted_at_the_second_clip)
    line = only_line(capsys, ["generate", "--root", "d", *SMALL], code=130)
    assert line == (
        "error: generate interrupted (Ctrl-C, SIGINT): the shards it finished are kept (a "
        "shard being written is left out whole); run the same command again to resume"
    )
    monkeypatch.setattr(render, "render_record", render_record)
    main(["generate", "--root", "d", *SMALL])
    assert "1 shards generated (1 records" in capsys.readouterr().out  # the first was kept


# ----------------------------------------------------------------------------- usage blocks
@pytest.mark.parametrize(
    "arguments,expected",
    [
        (
            ["fit", "--config", TINY_CONFIG, "--data.init_args.seed_offset", "1e6"],
            "error: --data.init_args.seed_offset: expected an integer (int), got 1e6 (read as "
            "1000000.0, a number with an exponent or a point is a float: write 1000000)",
        ),
        (
            ["generate", "--root", "d", "--seed_offset", "1e6"],
            "error: --seed_offset: expected an integer (int), got 1000000.0 (a number with an "
            "exponent or a point is a float: write 1000000)",
        ),
        (
            ["fit", "--config", TINY_CONFIG, "--data.init_args.concept", "gravity"],
            "error: --data.init_args.concept: expected one of object_persistence, "
            "unchangeableness, continuity, solidity, containment, got gravity",
        ),
    ],
)
def test_a_value_of_the_wrong_type_is_one_line_naming_argument_value_and_type(
    workdir, capsys, arguments, expected
):
    assert only_line(capsys, arguments) == expected
    assert not (workdir / "data").exists() and not (workdir / "d").exists()


def test_a_model_missing_a_method_names_it_from_the_flag_or_a_config(workdir, capsys):
    model = "test_one_line_errors.NoTrajectories"
    line = only_line(capsys, ["test", "--config", TINY_CONFIG, "--model", model])
    assert f"--model {model} cannot be built: it does not implement trajectories" in line
    (workdir / "model.yaml").write_text(yaml.safe_dump({"model": {"class_path": model}}))
    config = ["--config", TINY_CONFIG, "--config", "model.yaml"]
    line = only_line(capsys, ["test", *config])
    assert f"--model {model} cannot be built: it does not implement trajectories" in line


@pytest.mark.parametrize(
    "class_path,reason",
    [
        ("voe_lightning.model.NoSuchModel", "module 'voe_lightning.model' has no attribute"),
        ("no_such_package.Model", "No module named 'no_such_package'"),
    ],
)
def test_an_unknown_class_path_in_a_config_is_one_line_naming_it(
    workdir, capsys, class_path, reason
):
    (workdir / "model.yaml").write_text(yaml.safe_dump({"model": {"class_path": class_path}}))
    line = only_line(capsys, ["fit", "--config", TINY_CONFIG, "--config", "model.yaml"])
    assert line.startswith(f"error: --model.class_path {class_path} cannot be imported ({reason}")
    assert "e.g. voe_lightning.model.VRNNLRUModel" in line


@pytest.mark.parametrize("text", ["", "null\n", "# only a comment\n", "~\n"])
def test_an_empty_or_null_config_is_one_line(workdir, capsys, text):
    (workdir / "empty.yaml").write_text(text)
    for command in (["fit"], ["generate", "--root", "d"]):
        line = only_line(capsys, [*command, "--config", "empty.yaml"])
        assert line.startswith("error: --config empty.yaml is empty (or null): a config is a")


def test_a_config_of_a_list_is_one_line(workdir, capsys):
    (workdir / "list.yaml").write_text("- 1\n- 2\n")
    line = only_line(capsys, ["fit", "--config", "list.yaml"])
    assert "--config list.yaml holds a list, not a mapping of arguments" in line


def test_debug_shows_the_parsers_whole_message(workdir, capsys):
    with pytest.raises(SystemExit):
        main(["generate", "--root", "d", "--seed_offset", "1e6", "--debug"])
    err = capsys.readouterr().err
    assert "usage:" in err and "Expected a <class 'int'>. Got value: 1000000.0" in err


@pytest.mark.parametrize(
    "message,expected",
    [
        ("unrecognized arguments: --x 1", "unrecognized arguments: --x 1"),
        (
            'Parser key "trainer.precision":\n  Does not validate against any of the Union '
            "subtypes\n  Subtypes: [...]\n  Errors:\n    - Expected a typing.Literal[64, 32]\n"
            "    - Expected a typing.Literal['bf16-mixed', 32]\n    - Expected a <class "
            "'NoneType'>\n  Given value type: <class 'int'>\n  Given value: 17",
            "--trainer.precision: expected one of 64, 32, bf16-mixed, got 17",
        ),
        (
            'Parser key "data":\n  Does not validate against any of the Union subtypes\n'
            "  Errors:\n    - Problem with given class_path 'voe_lightning.datamodules.ConceptDataModule':\n"
            "        Option 'no_such_key' is not accepted\n    - Expected a <class 'NoneType'>\n"
            "  Given value: NestedArg(key='no_such_key', val='1')",
            "--data.init_args.no_such_key: voe_lightning.datamodules.ConceptDataModule takes no argument "
            "no_such_key; it takes concept, concepts, root,",
        ),
    ],
)
def test_the_parsers_nested_messages_read_as_one_line(message, expected):
    line = one_line(message)
    assert "\n" not in line and line.startswith(expected), line


# ----------------------------------------------------------------------------- not said
def test_the_readme_and_reliability_say_configs_and_checkpoints_are_code():
    for document in ("README.md", "docs/reliability.md"):
        text = " ".join((REPO / document).read_text().split())
        assert "configs and checkpoints are code" in text.lower(), document
        assert "people you trust" in text, document
