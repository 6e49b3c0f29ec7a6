"""docs/your_model.md, run: a video model defined outside the package (a SurpriseModel subclass
in the user's own module, or a plain callable frames -> per-frame surprise wrapped by
CallableModel) is scored by ``test`` through ``--model``, with no checkpoint, and a callable
that returns the wrong shape is named."""

import json
import sys

import pytest
import torch
from helpers.locations import TINY_CONFIG

from voe_lightning.cli import main
from voe_lightning.model import CallableModel

USER_MODULE = '''
import torch

from voe_lightning import specs
from voe_lightning.model import SurpriseModel


class Brightness(SurpriseModel):
    """Surprise = how much brighter frame t is than frame t - 1."""

    def surprise(self, frames, mask=None, camera=None, objects=None):
        brightness = frames.float().mean(dim=(2, 3, 4))
        return torch.cat([torch.zeros_like(brightness[:, :1]),
                          (brightness[:, 1:] - brightness[:, :-1]).abs()], dim=1)

    def expected_frames(self, frames, mask=None, camera=None, objects=None):
        return specs.to_model_input(frames)

    def trajectories(self, frames, mask=None, camera=None, objects=None):
        value = self.surprise(frames)
        return {"brightness": torch.stack([value, value.cumsum(1)], dim=-1)}


def frame_change(frames):
    x = frames.float()
    change = (x[:, 1:] - x[:, :-1]).abs().mean(dim=(2, 3, 4))
    return torch.cat([torch.zeros_like(change[:, :1]), change], dim=1)


def wrong_shape(frames):
    return torch.zeros(frames.shape[0])
'''


@pytest.fixture()
def user_module(tmp_path, monkeypatch):
    (tmp_path / "my_video_models.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    yield tmp_path
    sys.modules.pop("my_video_models", None)


@pytest.mark.parametrize(
    "model",
    [
        ["--model", "my_video_models.Brightness"],
        [
            "--model",
            "voe_lightning.model.CallableModel",
            "--model.init_args.function",
            "my_video_models.frame_change",
        ],
    ],
    ids=["subclass", "callable"],
)
def test_a_model_from_outside_the_package_is_tested_without_a_checkpoint(user_module, model):
    main(["test", "--config", TINY_CONFIG, *model, "--trainer.enable_progress_bar", "false"])
    summary = json.loads(
        (user_module / "runs" / "tiny" / "version_0" / "voe_report" / "summary.json").read_text()
    )
    assert {row["variant"] for row in summary["rows"]} == {
        "standard",
        "counterbalanced",
        "pooled",
        "quadruplet",
    }


def test_a_callable_of_the_wrong_shape_or_path_is_named(user_module):
    with pytest.raises(
        ValueError,
        match=r"my_video_models.wrong_shape returned surprise of "
        r"shape \(2,\) for frames \(2, 3, 4, 4, 3\)",
    ):
        CallableModel("my_video_models.wrong_shape").surprise(
            torch.zeros(2, 3, 4, 4, 3, dtype=torch.uint8)
        )
    with pytest.raises(ValueError, match=r"function 'my_video_models.missing' cannot be imported"):
        CallableModel("my_video_models.missing")
