"""``python -m voe_lightning migrate PATH`` turns a run saved before each name had one path
(issue 57) into one that today's code reads: its config's and checkpoint's class paths, the
arguments its classes no longer take, and whatever its checkpoint pickles under an old module."""

import sys
import zipfile

import pytest
import torch
import yaml
from helpers.locations import TINY_CONFIG
from helpers.runs import copy_of

from voe_lightning.cli import main
from voe_lightning.migration import MOVED_MODULES, RENAMED_CLASSES, new_path
from voe_lightning.model.vrnn_lru.model import VRNNLRUModel
from voe_lightning.stats import surprise_window
from voe_lightning.stats.surprise_window import SurpriseWindow

#: The VRNN-LRU's class path in a run saved before issue 49 and 26: its old module, its old name.
OLD_MODEL = (
    "voe_lightning.model.module." + {v: k for k, v in RENAMED_CLASSES.items()}["VRNNLRUModel"]
)
#: A model argument the VRNN-LRU took before issue 57 (the earlier switch of ``compile``).
RETIRED = "_".join(("compile", "model"))


def test_old_module_paths_and_names_become_those_of_today():
    assert new_path(OLD_MODEL) == "voe_lightning.model.vrnn_lru.model.VRNNLRUModel"
    assert new_path("voe_lightning.statistics") == "voe_lightning.stats.statistics"
    assert new_path("voe_lightning.prediction_writer.IntPhysAnswerWriter") == (
        "voe_lightning.callbacks.prediction_writer.IntPhysAnswerWriter"
    )
    assert new_path("voe_lightning.model.VRNNLRUModel") == "voe_lightning.model.VRNNLRUModel"
    assert new_path("datamodules.voe.ConceptDataModule") == (
        "voe_lightning.datamodules.voe.ConceptDataModule"
    )
    assert new_path("voe_lightning.external.intphys2.VideoDataset") == (
        "voe_lightning.benchmarks.intphys2.reader.VideoDataset"
    )
    assert new_path("voe_lightning.null.run_null") == "voe_lightning.analysis.null.run_null"
    assert len(MOVED_MODULES) == 63 and not any(  # no path of today is rewritten again
        new == old or new.startswith(f"{old}.")
        for new in MOVED_MODULES.values()
        for old in MOVED_MODULES
    )


def test_a_config_naming_a_benchmark_datamodule_by_its_old_path_names_its_home(tmp_path):
    """Issue 71: each benchmark's DataModule moved into its home, ``voe_lightning.benchmarks``."""
    old, new = (
        "voe_lightning.datamodules.IntPhysDataModule",
        "voe_lightning.benchmarks.intphys.IntPhysDataModule",
    )
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump({"data": {"class_path": old, "init_args": {"root": "x"}}}))
    assert main(["migrate", str(config)]) == [f"{config}: data.class_path: {old} -> {new}"]
    assert yaml.safe_load(config.read_text()) == {
        "data": {"class_path": new, "init_args": {"root": "x"}}
    }


@pytest.mark.slow
def test_a_run_saved_before_the_change_tests_after_migrate(workdir, trained, capsys):
    """The run as the parent commit saved it: the model under its old path and name, with an
    argument it no longer takes, in config.yaml and in the checkpoint's hyperparameters."""
    run = copy_of(trained, workdir)
    config = yaml.safe_load((run / "config.yaml").read_text())
    config["model"]["class_path"] = OLD_MODEL
    config["model"]["init_args"][RETIRED] = False
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    checkpoint = run / "checkpoints" / "last.ckpt"
    stored = torch.load(checkpoint, weights_only=True)
    stored["hyper_parameters"].update({"_class_path": OLD_MODEL, RETIRED: False})
    torch.save(stored, checkpoint)
    with pytest.raises(SystemExit):  # today's code refuses it, naming migrate
        main(["test", "--config", TINY_CONFIG, "--ckpt_path", str(checkpoint)])
    assert "python -m voe_lightning migrate" in capsys.readouterr().err

    changes = main(["migrate", str(run)])
    assert f"{checkpoint}: hyper_parameters: dropped {RETIRED}: False" in changes
    assert f"{run / 'config.yaml'}: model.class_path: {OLD_MODEL} -> {new_path(OLD_MODEL)}" in (
        changes
    )
    assert (run / "config.yaml.before-migrate").is_file()
    assert (run / "checkpoints" / "last.ckpt.before-migrate").is_file()
    assert main(["migrate", str(run)]) == []  # once is enough
    assert isinstance(
        VRNNLRUModel.load_from_checkpoint(checkpoint, weights_only=True), VRNNLRUModel
    )
    main(["test", "--config", TINY_CONFIG, "--ckpt_path", str(checkpoint)])
    assert (run / "voe_report" / "summary.json").is_file()


def test_an_object_pickled_under_its_old_module_path_is_pickled_under_its_new_one(
    tmp_path, monkeypatch
):
    old = "voe_lightning.surprise_window"
    checkpoint = tmp_path / "old.ckpt"
    with monkeypatch.context() as patch:  # pickle it as the parent commit did
        patch.setattr(SurpriseWindow, "__module__", old)
        patch.setitem(sys.modules, old, surprise_window)
        torch.save({"window": SurpriseWindow(4)}, checkpoint)
    with pytest.raises(ModuleNotFoundError, match=old):
        torch.load(checkpoint, weights_only=False)
    assert main(["migrate", str(checkpoint)]) == [
        f"{checkpoint}: pickled {old}.SurpriseWindow -> {surprise_window.__name__}.SurpriseWindow"
    ]
    assert torch.load(checkpoint, weights_only=False) == {"window": SurpriseWindow(4)}
    with zipfile.ZipFile(checkpoint) as archive:
        pickled = b"".join(
            archive.read(name) for name in archive.namelist() if name.endswith(".pkl")
        )
    assert old.encode() not in pickled and surprise_window.__name__.encode() in pickled


@pytest.mark.parametrize("name", ["notes.txt", "missing.ckpt", "empty_folder"])
def test_a_path_that_is_no_run_config_or_checkpoint_is_refused_in_one_line(workdir, capsys, name):
    (workdir / "notes.txt").write_text("not a run")
    (workdir / "empty_folder").mkdir()
    with pytest.raises(SystemExit) as raised:
        main(["migrate", name])
    assert raised.value.code == 2
    error = capsys.readouterr().err.strip()
    assert error == (
        f"error: migrate: {name} is not a run folder, config or checkpoint; give a folder "
        "holding a run's .yaml or .ckpt files, a config .yaml or a checkpoint .ckpt"
    )
