"""The convolutional observation networks of the VRNN (paper Appendix A): a ResNet-style encoder
and its transpose, a decoder of size-preserving convolutions followed by upsampling. Both take
any leading dimensions (e.g. [B, T]) and fold them into one batch, so all frames run at once."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn


def _check_channels(channels: Sequence[int]) -> tuple[int, int, int]:
    channels = tuple(int(c) for c in channels)
    if len(channels) != 3 or min(channels) < 1:
        raise ValueError(
            f"channels must be three positive sizes (1x1, 3x3, 1x1 convolutions), got {channels}"
        )
    return channels


def feature_map_size(height: int, width: int, num_blocks: int) -> tuple[int, int]:
    """Spatial size after ``num_blocks`` stride-2 blocks; refuses sizes that do not halve evenly."""
    factor = 2**num_blocks
    if num_blocks < 1 or height % factor or width % factor:
        raise ValueError(
            f"image size {height}x{width} must be divisible by 2**num_blocks = {factor} "
            f"(num_blocks={num_blocks}); choose fewer blocks or a size that is a multiple of {factor}"
        )
    return height // factor, width // factor


def _memory_format(module: nn.Module, channels_last: bool) -> torch.memory_format:
    """Put ``module``'s convolution weights in the chosen layout and return that layout."""
    memory_format = torch.channels_last if channels_last else torch.contiguous_format
    module.to(memory_format=memory_format)  # type: ignore[call-overload]  # torch: Module.to takes memory_format, its overloads omit it
    return memory_format


class PixelShuffle(nn.PixelShuffle):
    """``nn.PixelShuffle`` that keeps a channels-last input channels-last, as one permuted copy
    (aten's kernel takes about twice as long on that layout)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not x.is_contiguous(memory_format=torch.channels_last) or x.is_contiguous():
            return super().forward(x)
        r = self.upscale_factor
        n, c, h, w = x.shape
        nhwc = x.permute(0, 2, 3, 1).reshape(n, h, w, c // r**2, r, r).permute(0, 1, 4, 2, 5, 3)
        return nhwc.reshape(n, h * r, w * r, c // r**2).permute(0, 3, 1, 2)


class Bottleneck(nn.Module):
    """1x1 -> 3x3 -> 1x1 convolutions with a ReLU only after the block (paper Appendix A) and a
    1x1 shortcut projection (identity when shapes agree). ``stride`` 2 halves the size.

    The strided shortcut subsamples, then applies a stride-1 1x1 convolution: the same map and
    parameters as a stride-2 1x1 convolution, without torch 2.13's CPU (oneDNN) kernel whose
    backward crashes on channels-last input with 3 channels."""

    def __init__(self, in_channels: int, channels: Sequence[int], stride: int = 1) -> None:
        super().__init__()
        reduce, middle, out = _check_channels(channels)
        self.convs = nn.Sequential(
            nn.Conv2d(in_channels, reduce, kernel_size=1),
            nn.Conv2d(reduce, middle, kernel_size=3, stride=stride, padding=1),
            nn.Conv2d(middle, out, kernel_size=1),
        )
        self.shortcut = (
            nn.Identity()
            if stride == 1 and in_channels == out
            else nn.Conv2d(in_channels, out, kernel_size=1)
        )
        self.stride = stride

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        shortcut = self.shortcut(x[..., :: self.stride, :: self.stride] if self.stride > 1 else x)
        return torch.relu(self.convs(x) + shortcut)


class Encoder(nn.Module):
    """Frames [..., 3, H, W] in [0, 1] -> features [..., mlp_size].

    ``num_blocks`` stride-2 bottleneck blocks (channels 1x1, 3x3, 1x1; paper: 6 blocks of 64, 64,
    128), then a ReLU MLP layer of ``mlp_size`` units (paper: 500). H and W must be divisible by
    ``2**num_blocks``. ``channels_last`` keeps weights and activations in NHWC layout (the fast
    layout of oneDNN and cuDNN; same numbers as NCHW up to summation order).
    """

    def __init__(
        self,
        image_size: Sequence[int] = (64, 64),
        num_blocks: int = 6,
        channels: Sequence[int] = (64, 64, 128),
        mlp_size: int = 500,
        in_channels: int = 3,
        channels_last: bool = False,
    ) -> None:
        super().__init__()
        height, width = image_size
        channels = _check_channels(channels)
        self.map_size = feature_map_size(height, width, num_blocks)
        self.in_channels = in_channels
        self.output_size = mlp_size
        blocks, previous = [], in_channels
        for _ in range(num_blocks):
            blocks.append(Bottleneck(previous, channels, stride=2))
            previous = channels[-1]
        self.blocks = nn.Sequential(*blocks)
        flat = channels[-1] * self.map_size[0] * self.map_size[1]
        self.mlp = nn.Sequential(nn.Flatten(), nn.Linear(flat, mlp_size), nn.ReLU())
        self.memory_format = _memory_format(self, channels_last)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        leading = frames.shape[:-3]
        # specs.to_model_input already gives a channels-last view: no copy on the fast path.
        frames = frames.reshape(-1, *frames.shape[-3:]).contiguous(memory_format=self.memory_format)
        features: torch.Tensor = self.mlp(self.blocks(frames))
        return features.reshape(*leading, self.output_size)


class Decoder(nn.Module):
    """Latents [..., latent_size] -> Bernoulli logits [..., 3, H, W].

    The encoder transposed: a ReLU MLP layer (``mlp_size``) and a linear map to the encoder's
    final feature map, then ``num_blocks`` size-preserving bottleneck blocks (1x1, 3x3 channels
    reversed: ``channels[1], channels[0], channels[2]``), each followed by 2x upsampling. The
    first ``num_blocks - 1`` upsamplings are nearest-neighbour; the last one is a sub-pixel
    convolution (Shi et al. 2016): a size-preserving 3x3 convolution to ``3 * 4`` logit channels
    and a pixel shuffle. It can express everything nearest upsampling followed by a 3x3
    convolution can, without materialising a full-resolution feature map (on a CPU that map
    cost about half the training step). ``channels_last`` as for :class:`Encoder`.
    """

    def __init__(
        self,
        latent_size: int,
        image_size: Sequence[int] = (64, 64),
        num_blocks: int = 6,
        channels: Sequence[int] = (64, 64, 128),
        mlp_size: int = 500,
        out_channels: int = 3,
        channels_last: bool = False,
    ) -> None:
        super().__init__()
        height, width = image_size
        channels = _check_channels(channels)
        self.map_size = feature_map_size(height, width, num_blocks)
        self.image_size = (height, width)
        self.out_channels = out_channels
        self.map_channels = channels[-1]
        flat = channels[-1] * self.map_size[0] * self.map_size[1]
        self.mlp = nn.Sequential(
            nn.Linear(latent_size, mlp_size), nn.ReLU(), nn.Linear(mlp_size, flat), nn.ReLU()
        )
        transposed = (channels[1], channels[0], channels[2])
        layers: list[nn.Module] = []
        for block in range(num_blocks):
            layers.append(Bottleneck(channels[-1], transposed))
            if block < num_blocks - 1:
                layers.append(nn.Upsample(scale_factor=2.0))
        self.blocks = nn.Sequential(*layers)
        self.logits = nn.Sequential(
            nn.Conv2d(channels[-1], out_channels * 4, kernel_size=3, padding=1), PixelShuffle(2)
        )
        self.memory_format = _memory_format(self, channels_last)

    def forward(self, latents: torch.Tensor) -> torch.Tensor:
        leading = latents.shape[:-1]
        features = self.mlp(latents.reshape(-1, latents.shape[-1]))
        features = features.view(-1, self.map_channels, *self.map_size).contiguous(
            memory_format=self.memory_format
        )
        logits: torch.Tensor = self.logits(self.blocks(features))
        return logits.reshape(*leading, self.out_channels, *self.image_size)
