"""A maintained library's predictive video model as a ``SurpriseModel``: VideoMAE (Tong et al.
2022) through Hugging Face transformers' ``VideoMAEForPreTraining``, loaded from a local folder
(never from the network) or built at random from a config (tests). Surprise is the model's own
masked-reconstruction error of what comes next, as pixel-space predictive models are scored in
the V-JEPA intuitive-physics evaluation."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase

from voe_lightning.model.scorers.pretrained import PretrainedScorer, transformers_module


class VideoMAEScorer(PretrainedScorer):
    """Per-frame surprise from VideoMAE's masked reconstruction, causally: for each tubelet k
    (``tubelet_size`` frames) the model sees tubelets 0..k-1 only (every later one masked) and
    reconstructs tubelet k; its mean squared error (over pixels, or per-patch-normalized pixels
    when the model was trained with ``norm_pix_loss``) is the surprise of the tubelet's last
    frame, 0 elsewhere (the first tubelet has nothing to be predicted from, an incomplete last
    tubelet no last frame). A video shorter than the model's ``num_frames`` is padded (by
    repeating its last frame; the padding is always masked), so cutting a video changes no
    surprise before the cut. Frozen: nothing here is trained, so ``test`` needs no
    checkpoint; ``image_size`` and ``training_frames`` are the model's, so benchmark
    DataModules take their geometry from it.

    Args:
        pretrained: a local folder holding a ``VideoMAEForPreTraining`` checkpoint
            (``config.json`` and weights), e.g. one saved with ``save_pretrained``.
        config: ``transformers.VideoMAEConfig`` arguments for a randomly initialised model
            instead (tests, or a model to train elsewhere).
    """

    SURPRISE = "VideoMAE's reconstruction error of the next tubelet"

    def __init__(self, pretrained: str | None = None, config: dict[str, Any] | None = None):
        transformers = transformers_module("VideoMAEScorer", "videomae", "4.45")
        super().__init__(
            transformers.VideoMAEForPreTraining, transformers.VideoMAEConfig, pretrained, config
        )
        settings = self.model.config
        if settings.num_frames % settings.tubelet_size:
            raise ValueError(
                f"num_frames {settings.num_frames} is not a multiple of tubelet_size "
                f"{settings.tubelet_size}"
            )
        self.save_hyperparameters()
        self.hparams["image_size"] = (settings.image_size, settings.image_size)
        self.hparams["training_frames"] = settings.num_frames

    # ----------------------------------------------------------------------------- helpers
    def _padded(self, frames: torch.Tensor) -> torch.Tensor:
        """uint8 [B, T, H, W, 3] -> [B, num_frames, 3, H, W] in [0, 1], the last frame repeated."""
        x = self._model_input(frames, tuple(self.hparams["image_size"]))
        total = self.model.config.num_frames
        if x.shape[1] > total:
            raise ValueError(
                f"videos of {x.shape[1]} frames are longer than this VideoMAE's "
                f"num_frames {total}; sample at most {total} frames"
            )
        return torch.cat([x, x[:, -1:].expand(-1, total - x.shape[1], -1, -1, -1)], dim=1)

    def patches(self, x: torch.Tensor, normalize: bool = True) -> torch.Tensor:
        """VideoMAE's reconstruction targets of x [B, T, 3, H, W] in [0, 1]: [B, tubelets,
        patches per tubelet, tubelet_size * patch_size^2 * 3], normalized per patch when the
        model was trained with ``norm_pix_loss`` and ``normalize`` (the layout its loss uses)."""
        settings = self.model.config
        b, t, c, h, w = x.shape
        ts, p = settings.tubelet_size, settings.patch_size
        patches = (
            x.view(b, t // ts, ts, c, h // p, p, w // p, p)
            .permute(0, 1, 4, 6, 2, 5, 7, 3)
            .reshape(b, t // ts, (h // p) * (w // p), ts * p * p, c)
        )
        if settings.norm_pix_loss and normalize:
            patches = (patches - patches.mean(dim=-2, keepdim=True)) / (
                patches.var(dim=-2, unbiased=True, keepdim=True).sqrt() + 1e-6
            )
        return patches.flatten(-2)

    def _predictions(self, x: torch.Tensor) -> list[torch.Tensor]:
        """For each tubelet k >= 1, the model's reconstruction of its patches [B, patches, D]
        from tubelets 0..k-1 alone."""
        settings = self.model.config
        tubelets = settings.num_frames // settings.tubelet_size
        per_tubelet = (settings.image_size // settings.patch_size) ** 2
        position = torch.arange(tubelets * per_tubelet, device=x.device)
        pixel_values = self.normalized(x)
        predictions = []
        for k in range(1, tubelets):
            masked = (position >= k * per_tubelet).expand(x.shape[0], -1)
            logits = self.model(pixel_values=pixel_values, bool_masked_pos=masked).logits
            predictions.append(logits[:, :per_tubelet])  # masked positions in order: k's first
        return predictions

    # ----------------------------------------------------------------------------- protocol
    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        length, ts = frames.shape[1], self.model.config.tubelet_size
        x = self._padded(frames)
        targets = self.patches(x)
        surprise = torch.zeros(x.shape[0], length, device=x.device)
        for k, predicted in enumerate(self._predictions(x), start=1):
            if (k + 1) * ts > length:  # the tubelet's last frame is not there (yet)
                break
            error = (predicted.float() - targets[:, k].float()).square().mean(dim=(1, 2))
            surprise[:, (k + 1) * ts - 1] = error
        return surprise

    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """Each tubelet as reconstructed from the earlier ones (the first: as seen), in [0, 1];
        a ``norm_pix_loss`` model's reconstruction is shown with each patch's own mean and
        spread, as its loss compares them."""
        settings = self.model.config
        x = self._padded(frames)
        b, _, c, h, w = x.shape
        ts, p = settings.tubelet_size, settings.patch_size
        seen = self.patches(x, normalize=False)
        expected = x.clone()
        for k, predicted in enumerate(self._predictions(x), start=1):
            if settings.norm_pix_loss:
                raw = seen[:, k].unflatten(-1, (ts * p * p, c))  # type: ignore[no-untyped-call]  # Tensor.unflatten: unannotated in torch
                predicted = predicted.unflatten(-1, (ts * p * p, c)) * raw.std(  # type: ignore[no-untyped-call]  # Tensor.unflatten: unannotated in torch
                    dim=-2, keepdim=True
                ) + raw.mean(dim=-2, keepdim=True)
            tubelet = (
                predicted.reshape(b, h // p, w // p, ts, p, p, c)
                .permute(0, 3, 6, 1, 4, 2, 5)
                .reshape(b, ts, c, h, w)
            )
            expected[:, k * ts : (k + 1) * ts] = tubelet.float().clamp(0, 1)
        return expected[:, : frames.shape[1]]
