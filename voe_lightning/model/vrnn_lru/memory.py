"""LRU external memory with an LSTM controller (Santoro et al. 2016 addressing, as used by the
VRNN-LRU of Gemici et al. 2017 and Piloto et al. 2018; docs/architecture.md §7).

The memory is stateless as a module: every step takes and returns an explicit
:class:`MemoryState` of tensors with a leading batch dimension, so batch rows never interact and
a rollout can be forked or replayed from any state.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

HEAD_MIXINGS = ("controller", "mean", "concat")
WRITE_CONTENTS = ("projection", "latent")


class MemoryState(NamedTuple):
    """Everything the memory carries from one step to the next (all batch-first).

    memory [B, slots, units]; usage [B, slots]; read_weights [B, heads, slots] (of the last read);
    mixed_read_weights [B, slots] (the last read weights combined over heads, used by the write);
    hidden, cell [B, controller] (the LSTM controller); read [B, read_size] (last read output).
    """

    memory: torch.Tensor
    usage: torch.Tensor
    read_weights: torch.Tensor
    mixed_read_weights: torch.Tensor
    hidden: torch.Tensor
    cell: torch.Tensor
    read: torch.Tensor


class Read(NamedTuple):
    """The result of one read: the output ``read`` [B, read_size], per-head ``weights``
    [B, heads, slots], their head mixture ``mixed_weights`` [B, slots] and the controller state
    ``hidden``, ``cell`` [B, controller] that produced the keys."""

    read: torch.Tensor
    weights: torch.Tensor
    mixed_weights: torch.Tensor
    hidden: torch.Tensor
    cell: torch.Tensor


def _check_choice(name: str, value: str, valid: tuple[str, ...]) -> None:
    if value not in valid:
        raise ValueError(f"unknown {name} {value!r}; valid choices are: {', '.join(valid)}")


class LRUMemory(nn.Module):
    """Least-recently-used memory addressed by an LSTM controller.

    One step is split in two because the VRNN needs the read before it can infer what to write:
    :meth:`read` runs the controller on ``[z_{t-1}, r_{t-1}]`` and reads ``M_{t-1}`` with
    content-based (cosine, softmax with strength beta) weights per head; :meth:`write` clears the
    least-used slot and writes ``a_t`` with ``w^w_t = sigmoid(alpha) w^r_{t-1} +
    (1 - sigmoid(alpha)) w^lu_{t-1}``, then updates usage ``w^u_t = gamma w^u_{t-1} + w^r_t + w^w_t``
    (``w^r_t`` summed over heads). ``w^lu_{t-1}`` is 1 on the ``least_used_slots`` slots of
    smallest usage (Santoro et al.'s n), 0 elsewhere. ``w^r_{t-1}`` is the previous step's read weights mixed over
    heads the same way the read output is, so a single write vector per step is written.

    Args:
        input_size: size of the latent ``z`` fed to the controller and (maybe) written.
        num_slots: memory slots (paper: 15).
        slot_size: units per slot (paper: 100).
        num_read_heads: read heads (paper: 3).
        controller_size: LSTM units (paper: 128).
        gamma: usage decay (Santoro et al.: 0.95).
        head_mixing: how the heads' reads become ``r_t`` (the paper: "weighted sum"):
            ``"controller"`` (default) weights from a softmax over a controller output,
            ``"mean"`` equal weights, ``"concat"`` concatenates the heads (``read_size`` =
            heads x units; the write then uses the mean of the heads' weights).
        write_content: what is written: ``"projection"`` (default) a linear map of
            ``[h_t, z_t]`` to ``slot_size``; ``"latent"`` ``z_t`` itself (needs
            ``input_size == slot_size``).
        controller_sees_read: whether the controller's input includes ``r_{t-1}`` besides
            ``z_{t-1}`` (default True, as in Gemici et al.'s LRU model; the paper's controller
            sees ``z_{t-1}`` and its own state only: False).
        least_used_slots: how many slots the least-used weights ``w^lu`` mark (Santoro et al.'s
            n, which they set to the number of reads; default 1). Ties go to the lowest slot
            index, so the choice is deterministic. Whatever n, only the single least-used slot
            is cleared before the write, as in Santoro et al.
        cosine_eps: added to norms in the cosine similarity so an empty slot has
            similarity 0 instead of NaN.
    """

    def __init__(
        self,
        input_size: int,
        num_slots: int = 15,
        slot_size: int = 100,
        num_read_heads: int = 3,
        controller_size: int = 128,
        gamma: float = 0.95,
        head_mixing: str = "controller",
        write_content: str = "projection",
        controller_sees_read: bool = True,
        least_used_slots: int = 1,
        cosine_eps: float = 1e-6,
    ) -> None:
        super().__init__()
        _check_choice("head_mixing", head_mixing, HEAD_MIXINGS)
        _check_choice("write_content", write_content, WRITE_CONTENTS)
        for name, value in (
            ("input_size", input_size),
            ("num_slots", num_slots),
            ("slot_size", slot_size),
            ("num_read_heads", num_read_heads),
            ("controller_size", controller_size),
        ):
            if value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value}")
        if not isinstance(controller_sees_read, bool):
            raise TypeError(
                f"controller_sees_read must be True or False, got {controller_sees_read!r}"
            )
        if (
            not isinstance(least_used_slots, int)
            or isinstance(least_used_slots, bool)
            or not 1 <= least_used_slots <= num_slots
        ):
            raise ValueError(
                f"least_used_slots must be an integer from 1 to the number of memory slots "
                f"({num_slots}), got {least_used_slots!r}"
            )
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma (usage decay) must be in [0, 1], got {gamma}")
        if write_content == "latent" and input_size != slot_size:
            raise ValueError(
                f"write_content='latent' writes z itself, so input_size ({input_size}) must equal "
                f"slot_size ({slot_size}); use write_content='projection' otherwise"
            )
        self.input_size = input_size
        self.num_slots = num_slots
        self.slot_size = slot_size
        self.num_read_heads = num_read_heads
        self.controller_size = controller_size
        self.gamma = gamma
        self.head_mixing = head_mixing
        self.write_content = write_content
        self.controller_sees_read = controller_sees_read
        self.least_used_slots = least_used_slots
        self.eps = cosine_eps
        self.read_size = slot_size * (num_read_heads if head_mixing == "concat" else 1)

        controller_input = input_size + (self.read_size if controller_sees_read else 0)
        self.controller = nn.LSTMCell(controller_input, controller_size)
        self.keys = nn.Linear(controller_size, num_read_heads * slot_size)
        self.strengths = nn.Linear(controller_size, num_read_heads)
        self.head_weights = (
            nn.Linear(controller_size, num_read_heads) if head_mixing == "controller" else None
        )
        self.write_gate = nn.Linear(controller_size, 1)
        self.write_projection = (
            nn.Linear(controller_size + input_size, slot_size)
            if write_content == "projection"
            else None
        )

    def initial_state(
        self,
        batch_size: int,
        device: torch.device | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> MemoryState:
        """Empty memory, zero usage, no previous read, zero controller state."""

        def zeros(*shape: int) -> torch.Tensor:
            return torch.zeros(batch_size, *shape, device=device, dtype=dtype)

        return MemoryState(
            memory=zeros(self.num_slots, self.slot_size),
            usage=zeros(self.num_slots),
            read_weights=zeros(self.num_read_heads, self.num_slots),
            mixed_read_weights=zeros(self.num_slots),
            hidden=zeros(self.controller_size),
            cell=zeros(self.controller_size),
            read=zeros(self.read_size),
        )

    def read(self, state: MemoryState, previous_latent: torch.Tensor) -> Read:
        """Controller step on ``[z_{t-1}, r_{t-1}]`` and a content-based read of ``M_{t-1}``."""
        controller_input = (
            torch.cat([previous_latent, state.read.to(previous_latent.dtype)], dim=-1)
            if self.controller_sees_read
            else previous_latent
        )
        hidden, cell = self.controller(controller_input, (state.hidden, state.cell))
        batch = hidden.shape[0]
        keys = self.keys(hidden).view(batch, self.num_read_heads, self.slot_size).float()
        strengths = F.softplus(self.strengths(hidden).float()).unsqueeze(-1)  # [B, heads, 1]
        memory = state.memory.float()
        similarity = torch.einsum("bhu,bsu->bhs", keys, memory) / (
            keys.norm(dim=-1, keepdim=True) * memory.norm(dim=-1).unsqueeze(1) + self.eps
        )
        weights = torch.softmax(strengths * similarity, dim=-1)  # [B, heads, slots]
        head_reads = torch.einsum("bhs,bsu->bhu", weights, memory)  # [B, heads, units]
        if self.head_mixing == "concat":
            read = head_reads.reshape(batch, self.read_size)
            mixture = torch.full_like(weights[..., 0], 1.0 / self.num_read_heads)
        else:
            if self.head_mixing == "controller":
                assert self.head_weights is not None  # built for head_mixing "controller"
                mixture = torch.softmax(self.head_weights(hidden).float(), dim=-1)
            else:
                mixture = torch.full_like(weights[..., 0], 1.0 / self.num_read_heads)
            read = torch.einsum("bh,bhu->bu", mixture, head_reads)
        mixed_weights = torch.einsum("bh,bhs->bs", mixture, weights)
        return Read(
            read=read, weights=weights, mixed_weights=mixed_weights, hidden=hidden, cell=cell
        )

    def write_weights(
        self, state: MemoryState, hidden: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(w^w_t, c_{t-1})``: the write weights, and the one-hot least-used slot ``c_{t-1}``
        that the write clears. ``w^lu_{t-1}`` marks the ``least_used_slots`` slots of smallest
        usage; ties go to the lowest index (a stable sort), so the choice is deterministic."""
        by_usage = state.usage.argsort(dim=-1, stable=True)
        least_used = torch.zeros_like(state.usage).scatter_(
            -1, by_usage[:, : self.least_used_slots], 1.0
        )
        cleared = torch.zeros_like(state.usage).scatter_(
            -1, by_usage[:, :1], 1.0
        )  # one-hot, no host sync
        gate = torch.sigmoid(self.write_gate(hidden).float())  # [B, 1]
        weights = gate * state.mixed_read_weights + (1.0 - gate) * least_used
        return weights, cleared

    def write(self, state: MemoryState, read: Read, latent: torch.Tensor) -> MemoryState:
        """Clear the least-used slot, write ``a_t`` (from ``z_t``), update usage."""
        weights, cleared = self.write_weights(state, read.hidden)
        if self.write_projection is not None:
            content = self.write_projection(
                torch.cat([read.hidden, latent.to(read.hidden.dtype)], -1)
            )
        else:
            content = latent
        content = content.float()
        memory = state.memory * (1.0 - cleared).unsqueeze(-1) + weights.unsqueeze(
            -1
        ) * content.unsqueeze(1)
        usage = self.gamma * state.usage + read.weights.sum(dim=1) + weights
        return MemoryState(
            memory=memory,
            usage=usage,
            read_weights=read.weights,
            mixed_read_weights=read.mixed_weights,
            hidden=read.hidden,
            cell=read.cell,
            read=read.read,
        )

    @staticmethod
    def flat_memory(state: MemoryState) -> torch.Tensor:
        """The memory matrix flattened to [B, slots * units] (e.g. for t-SNE)."""
        return state.memory.flatten(start_dim=1)
