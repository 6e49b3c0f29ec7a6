"""Renamed classes keep their old names (issue 26): LightningCLI's saved ``config.yaml`` of
earlier runs names ``voe_lightning.model.VOEModel`` and ``datamodules.JointDataModule``, and
their checkpoints name the model class in ``hyper_parameters['_class_path']``. Moved modules
keep their old paths (issue 49): ``voe_lightning.statistics`` is ``voe_lightning.stats.statistics``,
and a saved config's ``voe_lightning.prediction_writer.IntPhysAnswerWriter`` still loads."""

import importlib
import pickle

import pytest
import torch
import yaml
from locations import TINY_CONFIG
from test_cli import copy_of
from test_configs import parsed

from datamodules import JointDataModule, VOEDataModule
from voe_lightning import specs
from voe_lightning.callbacks import (
    ExpectationImages,
    FinalStepCheckpoint,
    InterruptCheckpoint,
    IntPhys2LeaderboardWriter,
    IntPhysAnswerWriter,
    VOEProbeCallback,
    VOEReportCallback,
    voe_table,
)
from voe_lightning.cli import main
from voe_lightning.model import (
    CallableModel,
    CueScorer,
    LRUMemory,
    ObjectCentricModel,
    ObjectStateModel,
    VideoMAEScorer,
    VJEPA2Scorer,
    VRNNLRUModel,
)
from voe_lightning.old_paths import OLD_PATHS
from voe_lightning.stats.surprise_window import SurpriseWindow

OLD_MODEL_PATHS = ("voe_lightning.model.VOEModel", "voe_lightning.model.module.VOEModel")


@pytest.mark.parametrize("class_path", OLD_MODEL_PATHS)
def test_the_old_model_names_are_the_vrnn_lru(class_path):
    module_name, _, name = class_path.rpartition(".")
    assert getattr(importlib.import_module(module_name), name) is VRNNLRUModel


def test_the_joint_datamodule_is_the_voe_datamodule_with_its_defaults():
    assert issubclass(JointDataModule, VOEDataModule)
    assert dict(JointDataModule().hparams) == dict(VOEDataModule().hparams)


def test_a_saved_config_naming_the_old_classes_parses(workdir):
    config = yaml.safe_load(open(TINY_CONFIG))
    config["model"]["class_path"] = "voe_lightning.model.VOEModel"
    config["data"] = {
        "class_path": "datamodules.JointDataModule",
        "init_args": {"root": "data/tiny", "train_examples": 4, "val_pairs": 2},
    }
    (workdir / "old.yaml").write_text(yaml.safe_dump(config))
    full = parsed("fit", "--config", str(workdir / "old.yaml"))
    assert full["model"]["init_args"]["latent_size"] == 8
    assert full["data"]["init_args"]["concepts"] == list(specs.CONCEPTS)


@pytest.mark.parametrize("class_path", OLD_MODEL_PATHS)
def test_a_checkpoint_saved_under_the_old_model_name_tests(workdir, trained, class_path):
    run = copy_of(trained, workdir)
    checkpoint = run / "checkpoints" / "last.ckpt"
    stored = torch.load(checkpoint, weights_only=True)
    assert stored["hyper_parameters"]["_class_path"].endswith(".VRNNLRUModel")
    stored["hyper_parameters"]["_class_path"] = class_path
    torch.save(stored, checkpoint)
    assert isinstance(
        VRNNLRUModel.load_from_checkpoint(checkpoint, weights_only=True), VRNNLRUModel
    )
    main(["test", "--config", TINY_CONFIG, "--ckpt_path", str(checkpoint)])
    assert (run / "voe_report" / "summary.json").is_file()


@pytest.mark.parametrize("old, new", sorted(OLD_PATHS.items()))
def test_an_old_module_path_is_the_module_at_its_new_path(old, new):
    assert importlib.import_module(old) is importlib.import_module(new)
    assert importlib.import_module(new).__spec__.name == new  # the old path changes nothing


def test_an_old_module_path_imports_from_the_package():
    from voe_lightning import cues, generate, statistics, store
    from voe_lightning.audit import cues as new_cues
    from voe_lightning.data import generate as new_generate
    from voe_lightning.data import store as new_store
    from voe_lightning.stats import statistics as new_statistics

    assert (cues, generate, statistics, store) == (
        new_cues,
        new_generate,
        new_statistics,
        new_store,
    )
    assert statistics.paired_test is new_statistics.paired_test


#: The flat modules of ``voe_lightning.model`` before its families had sub-packages (issue 49).
OLD_MODEL_MODULES = (
    "base",
    "callable_model",
    "code_likelihood",
    "cue_scorer",
    "dynamics",
    "likelihood",
    "memory",
    "module",
    "networks",
    "object_centric",
    "object_geometry",
    "object_state",
    "optimization",
    "perception",
    "pretrained",
    "slots",
    "training_monitor",
    "videomae",
    "vjepa2",
    "vrnn",
    "vrnn_lru",
)
#: Old modules whose name is now a family's package, with the names each defined: the package
#: exports them.
OLD_MODULE_NAMES = {
    "voe_lightning.model.vrnn_lru": (
        "ARCHITECTURE",
        "COMPILE_MODES",
        "LOSS_TERMS",
        "PRECISIONS",
        "VOEModel",
        "VRNNLRUModel",
        "bf16_is_fast",
    ),
    "voe_lightning.model.object_centric": (
        "ARCHITECTURE",
        "SURPRISES",
        "ObjectCentricModel",
        "build_networks",
        "matching_code_size",
        "parameter_count",
    ),
    "voe_lightning.model.object_state": (
        "ARCHITECTURE",
        "BOX_CENTRE",
        "BOX_HALF",
        "CAMERA_XYZ",
        "CARRIES",
        "COLOR",
        "FEATURES",
        "FLOOR_FEATURES",
        "Holding",
        "IDENTITY",
        "LEFT_OUT",
        "MAX_MOVE",
        "MOVING",
        "Mixture",
        "ORIENTATION",
        "ObjectStateModel",
        "Observations",
        "PAIR_FEATURES",
        "POSE",
        "POSITION",
        "PairNetwork",
        "SHAPES",
        "SIZE",
        "SLOT_TERMS",
        "SPHERE",
        "STATE_SIZE",
        "Slots",
        "observe",
        "slowed",
        "withheld_spans",
    ),
}


@pytest.mark.parametrize("name", OLD_MODEL_MODULES)
def test_every_old_model_module_path_imports(name):
    """Each is an old path of ``OLD_PATHS``, a shared module still there, or now a package."""
    path = f"voe_lightning.model.{name}"
    module = importlib.import_module(path)
    assert path in OLD_PATHS or path in OLD_MODULE_NAMES or module.__name__ == path
    assert (path in OLD_MODULE_NAMES) == hasattr(module, "__path__")


@pytest.mark.parametrize("old", sorted(OLD_MODULE_NAMES))
def test_an_old_module_that_is_now_a_package_exports_its_names(old):
    package = importlib.import_module(old)
    assert set(OLD_MODULE_NAMES[old]) <= set(package.__all__)
    for name in OLD_MODULE_NAMES[old]:
        value = getattr(package, name)
        assert getattr(value, "__module__", old).startswith(old)  # defined in the package


OLD_CLASS_PATHS = {
    "voe_lightning.callbacks.VOEProbeCallback": VOEProbeCallback,
    "voe_lightning.callbacks.VOEReportCallback": VOEReportCallback,
    "voe_lightning.callbacks.ExpectationImages": ExpectationImages,
    "voe_lightning.callbacks.FinalStepCheckpoint": FinalStepCheckpoint,
    "voe_lightning.callbacks.voe_table": voe_table,
    "voe_lightning.interruption.InterruptCheckpoint": InterruptCheckpoint,
    "voe_lightning.prediction_writer.IntPhysAnswerWriter": IntPhysAnswerWriter,
    "voe_lightning.prediction_writer.IntPhys2LeaderboardWriter": IntPhys2LeaderboardWriter,
    "voe_lightning.surprise_window.SurpriseWindow": SurpriseWindow,
    "voe_lightning.cli.main": main,
    "voe_lightning.model.vrnn_lru.VRNNLRUModel": VRNNLRUModel,
    "voe_lightning.model.memory.LRUMemory": LRUMemory,
    "voe_lightning.model.object_state.ObjectStateModel": ObjectStateModel,
    "voe_lightning.model.object_centric.ObjectCentricModel": ObjectCentricModel,
    "voe_lightning.model.cue_scorer.CueScorer": CueScorer,
    "voe_lightning.model.callable_model.CallableModel": CallableModel,
    "voe_lightning.model.videomae.VideoMAEScorer": VideoMAEScorer,
    "voe_lightning.model.vjepa2.VJEPA2Scorer": VJEPA2Scorer,
}


@pytest.mark.parametrize("class_path", sorted(OLD_CLASS_PATHS))
def test_an_old_class_path_loads_the_class(class_path):
    module_name, _, name = class_path.rpartition(".")
    assert getattr(importlib.import_module(module_name), name) is OLD_CLASS_PATHS[class_path]


def test_an_object_pickled_under_its_old_module_path_unpickles():
    new = pickle.dumps(SurpriseWindow(4), protocol=0)  # protocol 0 writes the module as text
    old = new.replace(b"voe_lightning.stats.surprise_window", b"voe_lightning.surprise_window")
    assert old != new
    assert pickle.loads(old) == SurpriseWindow(4)
