"""The recurrent core of the VRNN-LRU (paper §4, docs/architecture.md §7): per time step a controller read
of the LRU memory, a prior map from the read, a posterior map that corrects the prior with the
encoded frame, a latent sample, and a memory write. Only this core loops over time."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from voe_lightning.model.vrnn_lru.memory import LRUMemory, MemoryState

#: Log standard deviations are clipped to this range (paper §4).
LOG_STD_LIMIT = 10.0


def gaussian_kl_per_latent(
    mean_q: torch.Tensor, log_std_q: torch.Tensor, mean_p: torch.Tensor, log_std_p: torch.Tensor
) -> torch.Tensor:
    """Analytic KL(q || p) of diagonal Gaussians, one value per latent (last dim), in float32."""
    mean_q, log_std_q, mean_p, log_std_p = (
        x.float() for x in (mean_q, log_std_q, mean_p, log_std_p)
    )
    variance_ratio = torch.exp(2.0 * (log_std_q - log_std_p))
    mahalanobis = (mean_q - mean_p).square() * torch.exp(-2.0 * log_std_p)
    return log_std_p - log_std_q + 0.5 * (variance_ratio + mahalanobis - 1.0)


def gaussian_kl(
    mean_q: torch.Tensor, log_std_q: torch.Tensor, mean_p: torch.Tensor, log_std_p: torch.Tensor
) -> torch.Tensor:
    """Analytic KL(q || p) of diagonal Gaussians, summed over the last dim, in float32."""
    return gaussian_kl_per_latent(mean_q, log_std_q, mean_p, log_std_p).sum(-1)


def standard_normal_kl(mean: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Analytic KL(N(mean, exp(log_std)^2) || N(0, I)) summed over the last dim, in float32."""
    mean, log_std = mean.float(), log_std.float()
    return (-log_std + 0.5 * (torch.exp(2.0 * log_std) + mean.square() - 1.0)).sum(-1)


def mlp(input_size: int, hidden_sizes: Sequence[int], output_size: int) -> nn.Sequential:
    """Linear layers with tanh between them (the paper's prior and posterior maps)."""
    layers: list[nn.Module] = []
    previous = input_size
    for size in hidden_sizes:
        layers += [nn.Linear(previous, size), nn.Tanh()]
        previous = size
    layers.append(nn.Linear(previous, output_size))
    return nn.Sequential(*layers)


class FrameStep(NamedTuple):
    """What one time step gives (float32 distributions): its rows of :class:`VRNNOutput`."""

    prior_mean: torch.Tensor
    prior_log_std: torch.Tensor
    posterior_mean: torch.Tensor
    posterior_log_std: torch.Tensor
    z: torch.Tensor
    memory: torch.Tensor
    reads: torch.Tensor


@dataclass
class VRNNOutput:
    """Per-step results of a rollout, all batch-first [B, T, ...] (distributions in float32).

    kl is KL(posterior_t || prior_t) summed over latents: the per-frame surprise. memory is the
    memory matrix after step t's write, flattened (for t-SNE); reads are r_t."""

    prior_mean: torch.Tensor
    prior_log_std: torch.Tensor
    posterior_mean: torch.Tensor
    posterior_log_std: torch.Tensor
    z: torch.Tensor
    kl: torch.Tensor
    memory: torch.Tensor
    reads: torch.Tensor

    def kl_per_latent(self) -> torch.Tensor:
        """KL(posterior_t || prior_t) per latent [B, T, latent_size]; ``kl`` is its sum."""
        return gaussian_kl_per_latent(
            self.posterior_mean, self.posterior_log_std, self.prior_mean, self.prior_log_std
        )


class VRNNCore(nn.Module):
    """Steps the VRNN through time given encoded frames [B, T, embedding_size].

    Args:
        embedding_size: size of the encoder's output.
        latent_size: Gaussian latents (paper: 256).
        mlp_sizes: hidden layers of the prior and posterior maps (paper: 512, 512; tanh).
        memory: the LRU memory (owns the controller); its ``input_size`` must be ``latent_size``.
    """

    def __init__(
        self,
        embedding_size: int,
        latent_size: int,
        memory: LRUMemory,
        mlp_sizes: Sequence[int] = (512, 512),
    ) -> None:
        super().__init__()
        if memory.input_size != latent_size:
            raise ValueError(
                f"memory.input_size ({memory.input_size}) must equal latent_size ({latent_size})"
            )
        if not mlp_sizes:
            raise ValueError("mlp_sizes needs at least one hidden layer")
        self.embedding_size = embedding_size
        self.latent_size = latent_size
        self.memory = memory
        self.prior = mlp(memory.read_size, mlp_sizes, 2 * latent_size)
        # Posterior correction from [enc(x_t), r_t, prior_t]; the enc(x_t) part of the first
        # layer is applied to all frames at once before the time loop.
        self.posterior = mlp(
            embedding_size + memory.read_size + 2 * latent_size, mlp_sizes, 2 * latent_size
        )
        self._compiled_step: (
            Callable[
                [MemoryState, torch.Tensor, torch.Tensor, torch.Tensor | None],
                tuple[MemoryState, FrameStep],
            ]
            | None
        ) = None

    def _split(self, stats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, log_std = stats.float().chunk(2, dim=-1)
        return mean, log_std

    def step(
        self,
        state: MemoryState,
        z: torch.Tensor,
        frame_part: torch.Tensor,
        noise: torch.Tensor | None,
    ) -> tuple[MemoryState, FrameStep]:
        """One time step from the memory ``state`` and the last latent ``z`` [B, latent_size]:
        read, prior, posterior (``frame_part`` [B, hidden] is the frame's share of the
        posterior's first layer), ``z_t`` = posterior mean + std * ``noise`` (the mean itself
        when ``noise`` is None), write. A pure function of tensors, so it compiles whole
        (``fullgraph=True``: no host sync, no data-dependent shape)."""
        first = self.posterior[0]
        assert isinstance(first, nn.Linear)  # mlp's first layer
        read = self.memory.read(state, z)
        prior_mean, prior_log_std = self._split(self.prior(read.read))
        prior_log_std = prior_log_std.clamp(-LOG_STD_LIMIT, LOG_STD_LIMIT)
        hidden = frame_part + F.linear(
            torch.cat([read.read, prior_mean, prior_log_std], dim=-1).to(frame_part.dtype),
            first.weight[:, self.embedding_size :],
        )
        correction_mean, correction_log_std = self._split(self.posterior[1:](hidden))
        posterior_mean = prior_mean + correction_mean
        posterior_log_std = (prior_log_std + correction_log_std).clamp(
            -LOG_STD_LIMIT, LOG_STD_LIMIT
        )
        z = (
            posterior_mean
            if noise is None
            else posterior_mean + torch.exp(posterior_log_std) * noise
        )
        state = self.memory.write(state, read, z)
        return state, FrameStep(
            prior_mean,
            prior_log_std,
            posterior_mean,
            posterior_log_std,
            z,
            LRUMemory.flat_memory(state),
            read.read,
        )

    def draw_noise(
        self, batch: int, steps: int, device: torch.device, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """Standard normal noise for every step [T, B, latent_size], drawn at once (on a CPU the
        same numbers as T draws of [B, latent_size] when B * latent_size is a multiple of 16)."""
        return torch.randn((steps, batch, self.latent_size), generator=generator, device=device)

    def compile_step(self) -> None:
        """Compile :meth:`step` once (inductor, ``fullgraph=True``); :meth:`forward` then
        calls the compiled step for every frame (``compile: frame``)."""
        self._compiled_step = torch.compile(self.step, fullgraph=True)

    def __getstate__(self) -> dict[str, Any]:
        # A compiled function does not pickle (ddp_spawn, deepcopy): recompile after loading.
        return {**self.__dict__, "_compiled_step": None}

    def forward(
        self,
        embeddings: torch.Tensor,
        deterministic: bool = False,
        generator: torch.Generator | None = None,
        noise: torch.Tensor | None = None,
    ) -> VRNNOutput:
        """Roll out over T steps from ``z_0 = 0`` and an empty memory. ``deterministic`` uses the
        posterior mean as z_t (for surprise); otherwise z_t is a reparameterized sample with
        ``noise`` [T, B, latent_size] (drawn here from ``generator`` when not given)."""
        batch, steps, _ = embeddings.shape
        device = embeddings.device
        first = self.posterior[0]
        assert isinstance(first, nn.Linear)  # mlp's first layer
        # The enc(x_t) part of the posterior's first layer, for all frames at once.
        frame_part = F.linear(embeddings, first.weight[:, : self.embedding_size], first.bias)
        if not deterministic and noise is None:
            noise = self.draw_noise(batch, steps, device, generator)
        step = self._compiled_step or self.step
        state = self.memory.initial_state(batch, device=device)
        z = torch.zeros(batch, self.latent_size, device=device)
        if torch.is_grad_enabled():  # every step's inputs then need grad: one compiled graph
            state = MemoryState(*(tensor.requires_grad_() for tensor in state))
            z.requires_grad_()
        frames = []
        for t in range(steps):
            frame_noise: torch.Tensor | None = None
            if not deterministic:
                assert noise is not None  # drawn above when not given
                frame_noise = noise[t]
            state, output = step(state, z, frame_part[:, t], frame_noise)
            z = output.z
            frames.append(output)
        stacked = {
            name: torch.stack(values, dim=1)
            for name, values in zip(FrameStep._fields, zip(*frames))
        }
        kl = gaussian_kl(
            stacked["posterior_mean"],
            stacked["posterior_log_std"],
            stacked["prior_mean"],
            stacked["prior_log_std"],
        )
        return VRNNOutput(kl=kl, **stacked)
