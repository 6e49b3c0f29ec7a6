"""Shared test settings and fixtures: headless rendering, a working folder, one tiny trained run."""

import os

import pytest
from helpers.locations import TINY_CONFIG

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture()
def workdir(tmp_path, monkeypatch):
    """A fresh working folder, the current one for the test (runs/ and data/ go there)."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A one-step fit under runs/trained (not the config's logger name): its run directory."""
    from voe_lightning.cli import main

    folder = tmp_path_factory.mktemp("trained")
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        main(
            [
                "fit",
                "--config",
                TINY_CONFIG,
                "--trainer.max_steps",
                "1",
                "--trainer.logger.init_args.name",
                "trained",
            ]
        )
    return folder / "runs" / "trained" / "version_0"
