"""Renamed classes keep their old names (issue 26): LightningCLI's saved ``config.yaml`` of
earlier runs names ``voe_lightning.model.VOEModel`` and ``datamodules.JointDataModule``, and
their checkpoints name the model class in ``hyper_parameters['_class_path']``."""

import importlib

import pytest
import torch
import yaml
from test_cli import CONFIG, copy_of
from test_configs import parsed

from datamodules import JointDataModule, VOEDataModule
from voe_lightning import specs
from voe_lightning.cli import main
from voe_lightning.model import VRNNLRUModel

OLD_MODEL_PATHS = ("voe_lightning.model.VOEModel", "voe_lightning.model.module.VOEModel")


@pytest.mark.parametrize("class_path", OLD_MODEL_PATHS)
def test_the_old_model_names_are_the_vrnn_lru(class_path):
    module_name, _, name = class_path.rpartition(".")
    assert getattr(importlib.import_module(module_name), name) is VRNNLRUModel


def test_the_joint_datamodule_is_the_voe_datamodule_with_its_defaults():
    assert issubclass(JointDataModule, VOEDataModule)
    assert dict(JointDataModule().hparams) == dict(VOEDataModule().hparams)


def test_a_saved_config_naming_the_old_classes_parses(workdir):
    config = yaml.safe_load(open(CONFIG))
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
    main(["test", "--config", CONFIG, "--ckpt_path", str(checkpoint)])
    assert (run / "voe_report" / "summary.json").is_file()
