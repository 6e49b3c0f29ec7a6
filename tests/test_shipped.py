"""The shipped checkpoints: each loads with ``weights_only``, builds its config's model, and
``test --ckpt_path <name>`` re-tests it without training, in a run folder of its own."""

import shutil

import pytest
import torch
import yaml
from helpers.locations import REPO

from voe_lightning import runs, shipped
from voe_lightning.cli import main
from voe_lightning.model import ObjectStateModel


@pytest.mark.parametrize("name", sorted(shipped.SHIPPED))
def test_a_shipped_checkpoint_is_its_configs_model_in_weights_only(name):
    """Its file is the one recorded (SHA-256), holds only weights and hyper-parameters, was
    trained with every model argument its config sets, and its weights load into the model its
    hyper-parameters build."""
    entry = shipped.SHIPPED[name]
    path = shipped.FOLDER / f"{name}.ckpt"
    assert shipped._sha256(path) == entry.sha256
    checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    assert set(checkpoint) <= set(shipped.KEPT_KEYS)
    trained = yaml.safe_load((shipped.FOLDER / f"{name}.yaml").read_text())
    assert trained["seed_everything"] == entry.seed
    hyper_parameters = checkpoint["hyper_parameters"]
    config = yaml.safe_load((REPO / "configs" / f"{entry.config}.yaml").read_text())
    assert hyper_parameters["_class_path"] == config["model"]["class_path"]
    for key, value in config["model"]["init_args"].items():
        assert hyper_parameters[key] == value, key
    model = ObjectStateModel(**{k: v for k, v in hyper_parameters.items() if k[0] != "_"})
    model.load_state_dict(checkpoint["state_dict"], strict=True)


def test_unpacking_makes_a_run_folder_once_and_refuses_a_changed_copy(tmp_path):
    name = sorted(shipped.SHIPPED)[0]
    checkpoint = shipped.unpack(name, tmp_path)
    assert checkpoint == tmp_path / shipped.RUN_NAME / name / "checkpoints" / "last.ckpt"
    assert (checkpoint.parent.parent / runs.RUN_CONFIG).is_file()
    assert shipped.unpack(name, tmp_path) == checkpoint
    checkpoint.write_bytes(checkpoint.read_bytes() + b"0")
    with pytest.raises(ValueError, match="differs from the shipped checkpoint"):
        shipped.unpack(name, tmp_path)
    with pytest.raises(ValueError, match="no shipped checkpoint is named 'nothing'; shipped: "):
        shipped.unpack("nothing", tmp_path)


def test_test_of_a_shipped_name_retests_it_without_training(workdir):
    """``test --config oracle_states_15min --ckpt_path oracle_states_15min_s0`` scores the
    shipped weights on fresh probes (two quadruplets here) and reports under
    ``runs/shipped/<name>/``, beside the config it trained with."""
    name = "oracle_states_15min_s0"
    main(
        [
            "test",
            "--config",
            "oracle_states_15min",
            "--ckpt_path",
            name,
            "--data.init_args.root",
            "data/fresh",
            "--data.init_args.concepts",
            "[object_persistence]",
            "--data.init_args.test_pairs",
            "2",
            "--data.init_args.seed_offset",
            "9000000",
        ]
    )
    run = workdir / "runs" / shipped.RUN_NAME / name
    reports = runs.trained_reports(run)
    assert reports, sorted(str(path) for path in run.rglob("*"))
    summary = reports[-1].read_text()
    assert "object_persistence" in summary
    shutil.rmtree(workdir / "data")


def test_packing_a_run_keeps_its_weights_and_config_and_drops_the_rest(
    trained, tmp_path, monkeypatch
):
    """``pack`` (how a checkpoint comes to ship) writes the run's weights and hyper-parameters
    only, loadable with ``weights_only``, beside the run's config, and returns the file's
    SHA-256 for its ``SHIPPED`` entry."""
    monkeypatch.setattr(shipped, "FOLDER", tmp_path / "checkpoints")
    source = trained / "checkpoints" / "last.ckpt"
    target, sha256 = shipped.pack(source, "tiny_s0")
    assert target == tmp_path / "checkpoints" / "tiny_s0.ckpt"
    assert sha256 == shipped._sha256(target)
    packed = torch.load(target, map_location="cpu", weights_only=True)
    assert set(packed) == set(shipped.KEPT_KEYS)
    original = torch.load(source, map_location="cpu", weights_only=True)
    assert packed["hyper_parameters"] == original["hyper_parameters"]
    assert all(torch.equal(packed["state_dict"][k], v) for k, v in original["state_dict"].items())
    assert (tmp_path / "checkpoints" / "tiny_s0.yaml").read_text() == (
        trained / runs.RUN_CONFIG
    ).read_text()
