"""``ExpectationImages``: image strips of what the model expected to see, logged at each
validation run."""

from __future__ import annotations

from typing import Any, cast

import lightning as L
import torch
from lightning.pytorch.utilities import rank_zero_warn
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.callbacks.common import probe_names
from voe_lightning.model.base import (
    SurpriseModel,
    expected_frames_problem,
    inputs_read_by,
    video_inputs,
)


def _first_frames(video_input: Any, count: int) -> Any:
    """The first ``count`` frames of one video's input: a tensor [T, ...], or a TensorDict of
    per-frame leaves (``objects``, whose batch dims end before T)."""
    if isinstance(video_input, TensorDictBase):
        return video_input.apply(lambda leaf: leaf[:count])
    return video_input[:count]


class ExpectationImages(L.Callback):
    """At each validation run, logs to TensorBoard, for one fixed inconsistent validation probe
    per concept, the input frames above ``expected_frames`` (given the probe's mask and camera):
    what the model expected to see given the previous frames (the paper's Figure 5)."""

    def __init__(self, max_frames: int = 15):
        super().__init__()
        self.max_frames = max_frames
        #: Per concept, its probe's inconsistent video: ``frames`` and ``video_inputs``.
        self.examples: dict[str, dict[str, torch.Tensor | TensorDictBase]] = {}

    def on_validation_batch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
        dataloader_idx: int = 0,
    ) -> None:
        concept_names, _ = probe_names(trainer, type(self).__name__)
        frames = batch["inconsistent", "frames"]
        inputs = video_inputs(batch, "inconsistent", inputs_read_by(pl_module))
        for index, concept in enumerate(batch["concept"].tolist()):
            name = concept_names[concept]
            if name not in self.examples:  # the first probe of each concept, fixed over training
                self.examples[name] = {
                    key: value[index].detach().cpu()
                    for key, value in {"frames": frames, **inputs}.items()
                }

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or not trainer.is_global_zero or not self.examples:
            return
        experiment = getattr(trainer.logger, "experiment", None)
        if experiment is None or not hasattr(experiment, "add_image"):
            return
        for concept, example in self.examples.items():
            video = {
                key: _first_frames(value, self.max_frames)[None].to(pl_module.device)
                for key, value in example.items()
            }
            frames = example["frames"][: self.max_frames]
            model_frames = video.pop("frames")
            with torch.no_grad():
                # Any probe model's protocol; expected_frames_problem checks its answer.
                returned = cast(SurpriseModel, pl_module).expected_frames(model_frames, **video)
            if problem := expected_frames_problem(pl_module, returned, model_frames):
                rank_zero_warn(f"{problem}; no expected/ images logged")
                return
            expected = returned[0]
            strip = torch.cat(
                [specs.to_model_input(frames), expected.float().cpu().clamp(0, 1)], dim=-2
            )
            # [T, 3, 2H, W] -> [3, 2H, T*W]: input row above expectation row.
            image = strip.permute(1, 2, 0, 3).reshape(3, strip.shape[-2], -1)
            experiment.add_image(f"expected/{concept}", image, global_step=trainer.global_step)
