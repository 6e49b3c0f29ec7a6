"""PLATO's perception module: per object, an encoder maps the masked frame and the mask to a
code, a decoder maps the code back to the object's RGB and mask logits, and a frame is the
composition of its slots (a softmax over the slots' mask logits weighs their RGB)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from voe_lightning.model.object_centric.slots import Slots


class Perception(nn.Module):
    """Object autoencoder shared by all slots.

    Args:
        image_size: (H, W), divisible by ``2 ** len(channels)``.
        code_size: size of an object's code z_k.
        channels: output channels of the encoder's stride-2 3x3 convolutions (the decoder
            mirrors them with 2x upsampling and 3x3 convolutions).
        variational: the encoder gives a Gaussian (mean, log-std) whose sample is the code in
            training and whose mean is the code otherwise (a VAE); else a plain autoencoder.
        channels_last: convolutions in NHWC layout (the fast layout of oneDNN and cuDNN).
    """

    def __init__(
        self,
        image_size: tuple[int, int],
        code_size: int,
        channels: Sequence[int],
        variational: bool,
        channels_last: bool = True,
    ) -> None:
        super().__init__()
        height, width = image_size
        scale = 2 ** len(channels)
        if height % scale or width % scale:
            raise ValueError(
                f"image_size {tuple(image_size)} must be divisible by 2**len(channels) = {scale}"
            )
        self.code_size, self.variational = code_size, variational
        self.memory_format = torch.channels_last if channels_last else torch.contiguous_format
        self.grid = (channels[-1], height // scale, width // scale)
        layers, previous = [], 4  # RGB of the object alone, and its mask
        for out in channels:
            layers += [nn.Conv2d(previous, out, 3, stride=2, padding=1), nn.ReLU()]
            previous = out
        self.encoder = nn.Sequential(*layers, nn.Flatten())
        flat = channels[-1] * self.grid[1] * self.grid[2]
        self.to_code = nn.Linear(flat, code_size * (2 if variational else 1))
        self.from_code = nn.Sequential(nn.Linear(code_size, flat), nn.ReLU())
        layers = []
        for out in [*reversed(channels[:-1]), channels[0]]:
            layers += [
                nn.Upsample(scale_factor=2),
                nn.Conv2d(previous, out, 3, padding=1),
                nn.ReLU(),
            ]
            previous = out
        self.decoder = nn.Sequential(*layers, nn.Conv2d(previous, 4, 3, padding=1))

    def encode(self, x: torch.Tensor, masks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Frames [N, 3, H, W] and slot masks [N, S, H, W] -> code mean and log-std
        [N, S, code_size] (log-std zeros for a plain autoencoder)."""
        n, slots = masks.shape[:2]
        inputs = torch.cat([x[:, None] * masks[:, :, None], masks[:, :, None]], dim=2)
        inputs = inputs.flatten(0, 1).contiguous(memory_format=self.memory_format)
        code = self.to_code(self.encoder(inputs)).view(n, slots, -1)
        if not self.variational:
            return code, torch.zeros_like(code)
        mean, log_std = code.chunk(2, dim=-1)
        return mean, log_std.clamp(-10.0, 10.0)

    def decode(self, codes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Codes [N, S, code_size] -> each slot's RGB in [0, 1] [N, S, 3, H, W] and mask
        logits [N, S, H, W]."""
        n, slots = codes.shape[:2]
        grid = self.from_code(codes.flatten(0, 1)).view(-1, *self.grid)
        out = self.decoder(grid.contiguous(memory_format=self.memory_format)).float()
        out = out.view(n, slots, *out.shape[1:])
        return torch.sigmoid(out[:, :, :3]), out[:, :, 3]


def compose(
    rgb: torch.Tensor, mask_logits: torch.Tensor, present: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """A frame from its slots: weights = softmax over the present slots' mask logits
    [N, S, H, W] (absent slots weigh 0), frame = sum_k weight_k * rgb_k [N, 3, H, W]; returns
    (frame, log weights)."""
    logits = mask_logits.masked_fill(~present[:, :, None, None], float("-inf"))
    log_weights = F.log_softmax(logits, dim=1)
    frame = (log_weights.exp()[:, :, None] * rgb).sum(dim=1)
    return frame, log_weights


def autoencoder_terms(
    perception: Perception,
    x: torch.Tensor,
    slots: Slots,
    kl_weight: float,
    mask_loss_weight: float,
) -> dict[str, torch.Tensor]:
    """The perception's loss per clip on model inputs [B, T, 3, H, W] and their ``slots``:
    reconstruction = the squared error of the composed frames, summed over frames and pixels;
    mask = ``mask_loss_weight`` * cross-entropy of the composition weights against the true
    slot masks; kl = ``kl_weight`` * KL of the seen slots' codes to N(0, I) (VAE only; else 0).
    The codes are sampled in a VAE."""
    batch, steps = x.shape[:2]
    mean, log_std = perception.encode(x.flatten(0, 1), slots.masks.flatten(0, 1))
    codes = mean + log_std.exp() * torch.randn_like(mean) if perception.variational else mean
    rgb, logits = perception.decode(codes)
    composed, log_weights = compose(rgb, logits, slots.seen.flatten(0, 1))
    reconstruction = (composed - x.flatten(0, 1)).pow(2).sum() / batch
    seen = slots.masks.flatten(0, 1) > 0
    mask = -torch.where(seen, log_weights, torch.zeros_like(log_weights)).sum() / batch
    kl = 0.5 * (mean.pow(2) + (2 * log_std).exp() - 1 - 2 * log_std)
    kl = kl_weight * (kl * slots.seen.flatten(0, 1)[..., None]).sum() / batch
    if not perception.variational:
        kl = torch.zeros_like(kl)
    mask = mask_loss_weight * mask
    return {
        "loss": reconstruction + mask + kl,
        "reconstruction": reconstruction,
        "mask": mask,
        "kl": kl,
    }
