"""The mixture over each slot's next state and what shapes it: the inertia of the last move (a
given, ``inertia``) and laying an object down (the landing Gaussian, the prior a measurement
kept: ``landing_mean``)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from voe_lightning.model.object_state.geometry import (
    lying_on_floor,
    on_or_above_floor,
    pivoted_down,
)
from voe_lightning.model.object_state.state import IDENTITY, POSE, Slots

#: The largest move of a state in one frame interval, in each of the inertia and the learned
#: change (metres for positions; our fastest object, a falling block, moves 0.6 m a frame).
MAX_MOVE = 1.5


@dataclass
class Mixture:
    """A mixture over each slot's next state: ``means`` and ``log_std`` [B, S, K, 13] and the
    components' ``logits`` [B, S, K] (None for one Gaussian)."""

    means: torch.Tensor
    log_std: torch.Tensor
    logits: torch.Tensor | None

    def most_probable(self) -> torch.Tensor:
        """Each slot's most probable component's mean [B, S, 13]."""
        top = (
            self.logits.argmax(-1)
            if self.logits is not None
            else self.means.new_zeros(self.means.shape[:2], dtype=torch.long)
        )
        size = self.means.shape[-1]
        return self.means.gather(2, top[..., None, None].expand(-1, -1, 1, size))[:, :, 0]


def inertial_move(slots: Slots) -> torch.Tensor:
    """Where its last move takes each slot [B, S, state] (positions only, the state's first
    part): that move, bounded by ``MAX_MOVE``, so a hidden object's rollout cannot feed on
    itself and diverge."""
    move = slots.velocity
    return F.pad(move.clamp(-MAX_MOVE, MAX_MOVE), (0, slots.belief.shape[-1] - move.shape[-1]))


def landing_mean(moved: torch.Tensor, slots: Slots, pivot: bool) -> torch.Tensor:
    """The landing Gaussian's mean [B, S, 13]: the object where its pose ``moved`` to, as
    the object it is (size and colour kept), turned down about its lowest corner onto a
    known object's top or the floor (``pivot``), else laid flat on the floor."""
    landing = torch.cat([moved[..., POSE], slots.belief[..., IDENTITY]], dim=-1)
    if pivot:
        return pivoted_down(on_or_above_floor(landing), slots.belief, slots.shape, slots.known)
    return lying_on_floor(landing)
