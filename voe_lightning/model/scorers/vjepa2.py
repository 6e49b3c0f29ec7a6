"""V-JEPA 2 (Assran et al. 2025) as a ``SurpriseModel``, scored as the V-JEPA intuitive-physics
evaluation scores it (Garrido et al. 2025, arXiv:2502.11831; its IntPhys 2 protocol), through
Hugging Face transformers' ``VJEPA2Model`` loaded from a local folder (never from the network)
or built at random from a config (tests).

The protocol: the video is subsampled every ``frame_step``-th frame; windows of
``window_frames`` subsampled frames slide over it every ``window_stride`` frames; in each window
the encoder sees the first ``context_frames`` frames alone, the predictor predicts the features
of the remaining frames from them, and the window's surprise is the L1 distance (mean over
tokens and features) between that prediction and the layer-normed (no affine parameters)
features the encoder gives of the whole window, the target. The window's surprise is the
surprise of its last frame, so surprise at frame t reads frames up to t only; every other frame
scores 0, and a video shorter than one window scores 0 throughout. The published IntPhys 2 run
of V-JEPA 2 used windows of 48 frames at 256 x 256, a frame step of 10, a stride of 2 and
context lengths 12 to 42 in steps of 6 (``context_frames``; sweep it with
``surprise_per_context``). Its ``max_context_mode`` also scores shorter contexts on the first
window (all ending at the same frame); per-frame surprise has one value per frame, so it is
left out here.

transformers' ``VJEPA2Model`` holds one encoder, which serves both as the context encoder and
as the target encoder here (in training the target encoder is the context encoder's moving
average; the evaluation uses each checkpoint's own).
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.model.scorers.pretrained import PretrainedScorer, transformers_module


class VJEPA2Scorer(PretrainedScorer):
    """Per-frame surprise from V-JEPA 2's feature prediction over sliding windows (module
    docstring). Frozen: nothing here is trained, so ``test`` needs no checkpoint; frames of any
    size are resized (shorter side) and centre-cropped to the model's ``crop_size``, and
    ``image_size`` is that size, so benchmark DataModules decode at it unless told otherwise.

    Args:
        context_frames: subsampled frames the encoder sees in each window (a multiple of the
            model's ``tubelet_size``, fewer than ``window_frames``).
        pretrained: a local folder holding a ``VJEPA2Model`` checkpoint (``config.json`` and
            weights), e.g. one saved with ``save_pretrained``.
        config: ``transformers.VJEPA2Config`` arguments for a randomly initialised model
            instead (tests, untrained nulls).
        window_frames: subsampled frames per window, context included (a multiple of
            ``tubelet_size``); 48 in the published V-JEPA 2 run.
        frame_step: keep every ``frame_step``-th frame of the video; 10 in the published run
            on IntPhys 2's 30 frames per second (our probes have 15 frames: 1).
        window_stride: subsampled frames between the starts of two windows; 2 as published.
    """

    SURPRISE = "V-JEPA 2's L1 error of the predicted features of a window's last frames"

    def __init__(
        self,
        context_frames: int,
        pretrained: str | None = None,
        config: dict[str, Any] | None = None,
        window_frames: int = 48,
        frame_step: int = 10,
        window_stride: int = 2,
    ):
        transformers = transformers_module("VJEPA2Scorer", "vjepa2", "4.53")
        super().__init__(transformers.VJEPA2Model, transformers.VJEPA2Config, pretrained, config)
        self.save_hyperparameters()
        settings = self.model.config
        check_windows(
            context_frames, window_frames, frame_step, window_stride, settings.tubelet_size
        )
        self.hparams["image_size"] = (settings.crop_size, settings.crop_size)

    # ----------------------------------------------------------------------------- helpers
    def _subsampled(self, frames: torch.Tensor) -> torch.Tensor:
        """uint8 [B, T, H, W, 3] -> every ``frame_step``-th frame as the network's input
        [B, T', 3, S, S] (resized, centre-cropped to S = crop_size, ImageNet-normalized)."""
        x = specs.to_model_input(frames.to(self.device))[:, :: self.hparams["frame_step"]]
        b, t, c, h, w = x.shape
        size = self.model.config.crop_size
        if (h, w) != (size, size):
            scale = size / min(h, w)
            resized = F.interpolate(
                x.flatten(0, 1),
                size=(max(size, round(h * scale)), max(size, round(w * scale))),
                mode="bilinear",
                antialias=True,
                align_corners=False,
            )
            top, left = (resized.shape[-2] - size) // 2, (resized.shape[-1] - size) // 2
            x = resized[..., top : top + size, left : left + size].unflatten(0, (b, t))  # type: ignore[no-untyped-call]  # Tensor.unflatten: unannotated in torch
        return self.normalized(x)

    def _window_error(self, window: torch.Tensor, context_frames: int) -> torch.Tensor:
        """The L1 error [B] of the predictor's features of ``window``'s frames after its first
        ``context_frames`` (encoded alone) against the layer-normed encoder features of the
        whole window."""
        context = self.model.encoder(pixel_values_videos=window[:, :context_frames])
        context = context.last_hidden_state
        target = self.model.encoder(pixel_values_videos=window).last_hidden_state
        target = F.layer_norm(target, target.shape[-1:])
        seen, total, batch = context.shape[1], target.shape[1], window.shape[0]
        positions = torch.arange(total, device=window.device).expand(batch, -1)
        predicted: torch.Tensor = self.model.predictor(
            encoder_hidden_states=context,
            context_mask=[positions[:, :seen]],
            target_mask=[positions[:, seen:]],
        ).last_hidden_state
        return (predicted.float() - target[:, seen:].float()).abs().mean(dim=(1, 2))

    def surprise_per_context(
        self, frames: torch.Tensor, context_lengths: list[int]
    ) -> dict[int, torch.Tensor]:
        """Per-frame surprise [B, T] for each context length (the published sweep over
        context length), the windows and everything else as configured."""
        x = self._subsampled(frames)
        result = {}
        for context in context_lengths:
            check_windows(
                context,
                self.hparams["window_frames"],
                self.hparams["frame_step"],
                self.hparams["window_stride"],
                self.model.config.tubelet_size,
            )
            surprise = torch.zeros(frames.shape[0], frames.shape[1], device=x.device)
            for start, last in window_ends(
                x.shape[1],
                self.hparams["window_frames"],
                self.hparams["window_stride"],
                self.hparams["frame_step"],
            ):
                window = x[:, start : start + self.hparams["window_frames"]]
                surprise[:, last] = self._window_error(window, context)
            result[context] = surprise
        return result

    # ----------------------------------------------------------------------------- protocol
    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        context = self.hparams["context_frames"]
        return self.surprise_per_context(frames, [context])[context]

    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """The frames as seen: V-JEPA 2 predicts features, not pixels."""
        return specs.to_model_input(frames.to(self.device))


def check_windows(
    context_frames: int, window_frames: int, frame_step: int, window_stride: int, tubelet_size: int
) -> None:
    """Refuse, in one line, window settings the protocol cannot use."""
    for name, value in (("frame_step", frame_step), ("window_stride", window_stride)):
        if value < 1:
            raise ValueError(f"{name} must be at least 1, got {value}")
    if not 0 < context_frames < window_frames:
        raise ValueError(
            f"context_frames must be in 1..window_frames - 1 = {window_frames - 1}, "
            f"got {context_frames}"
        )
    for name, value in (("context_frames", context_frames), ("window_frames", window_frames)):
        if value % tubelet_size:
            raise ValueError(
                f"{name} {value} is not a multiple of the model's tubelet_size {tubelet_size}"
            )


def window_ends(
    subsampled_frames: int, window_frames: int, window_stride: int, frame_step: int
) -> list[tuple[int, int]]:
    """Each window's first subsampled frame and the video frame its surprise is given to (its
    last frame, in the original video's frame numbers): windows start at 0, window_stride, ...
    while they fit in ``subsampled_frames``."""
    return [
        (start, (start + window_frames - 1) * frame_step)
        for start in range(0, subsampled_frames - window_frames + 1, window_stride)
    ]
