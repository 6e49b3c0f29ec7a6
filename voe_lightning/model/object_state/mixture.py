"""The mixture over each slot's next state and the priors that shape it, given, not learned: the
inertia of the last move (slowing, falling faster), laying an object down (the landing
Gaussian) and holding what rests on another object (``hold``)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F

from voe_lightning.model.object_state.geometry import (
    lying_on_floor,
    on_or_above_floor,
    pivoted_down,
    resting_on,
)
from voe_lightning.model.object_state.state import (
    IDENTITY,
    POSE,
    POSITION,
    STATE_SIZE,
    Slots,
)

#: The largest move of a state in one frame interval, in each of the inertia and the learned
#: change (metres for positions; our fastest object, a falling block, moves 0.6 m a frame).
MAX_MOVE = 1.5
#: An object moves when it moved more than this many metres in its last frame interval.
MOVING = 0.02
#: The logit that takes a Gaussian out of the mixture (``falling_lands``): finite, so that its
#: share of the entropy is 0 * finite, not 0 * inf.
LEFT_OUT = -1.0e4


@dataclass
class Holding:
    """Which slots stay where they rest while unseen (``carry: support``):
    what each rests on, one-hot [B, S, S] (``resting_on``; zeros: the floor or nothing),
    whether it is held [B, S], and where, its belief moved by its support's predicted move
    [B, S, 13]."""

    rests: torch.Tensor
    holds: torch.Tensor
    state: torch.Tensor


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


def slowed(move: torch.Tensor, change: torch.Tensor) -> torch.Tensor:
    """The next move [..., 3] of an object that goes on slowing as its last ``move`` was slowed
    by its ``change`` (both [..., 3]): the move along the floor (x, y) less the part of the change
    that opposed it, never past standstill (it stops, it does not turn back); the vertical move,
    and a change that speeds the object up or turns it, are left as they were."""
    along_floor = move[..., :2]
    speed = along_floor.square().sum(-1, keepdim=True).add(1e-12).sqrt()
    braking = (-(change[..., :2] * along_floor).sum(-1, keepdim=True) / speed).clamp(min=0)
    kept = (1 - braking / speed).clamp(0, 1)
    return torch.cat([along_floor * kept, move[..., 2:]], dim=-1)


def inertial_move(slots: Slots, slowing: bool) -> torch.Tensor:
    """Where its last move takes each slot [B, S, state] (positions only, the state's first
    part): that move, slowed as it was slowing (``slowing``); bounded by ``MAX_MOVE``, so a
    hidden object's rollout cannot feed on itself and diverge."""
    move = slowed(slots.velocity, slots.acceleration) if slowing else slots.velocity
    return F.pad(move.clamp(-MAX_MOVE, MAX_MOVE), (0, slots.belief.shape[-1] - move.shape[-1]))


def landing_mean(moved: torch.Tensor, slots: Slots, pivot: bool) -> torch.Tensor:
    """The landing Gaussian's mean [B, S, 13]: the object where its pose ``moved`` to, as
    the object it is (size and colour kept), turned down about its lowest corner onto a
    known object's top or the floor (``pivot``), else laid flat on the floor."""
    landing = torch.cat([moved[..., POSE], slots.belief[..., IDENTITY]], dim=-1)
    if pivot:
        return pivoted_down(on_or_above_floor(landing), slots.belief, slots.shape, slots.known)
    return lying_on_floor(landing)


def hold(
    slots: Slots, mixture: Mixture, unseen: torch.Tensor, carry: str
) -> tuple[torch.Tensor, Mixture, Holding | None]:
    """The predicted states [B, S, 13], the mixture with its stopping Gaussian carried by
    what each slot rests on (``carry: support``), and the ``Holding``: an unseen slot
    resting on a known one is held there. Without the prior: the most probable means, the
    mixture, None."""
    predicted = mixture.most_probable()
    if carry != "support":
        return predicted, mixture, None
    belief, known = slots.belief, slots.known
    rests = resting_on(belief.detach(), slots.shape, known)  # what rests on a known object
    moves = ((predicted - belief)[..., POSITION] * known[..., None]).detach()  # moves with it
    carried = F.pad(torch.einsum("bij,bjk->bik", rests, moves), (0, STATE_SIZE - 3))
    stopping = on_or_above_floor(mixture.means[:, :, 0] + carried)[:, :, None]
    mixture = replace(mixture, means=torch.cat([stopping, mixture.means[:, :, 1:]], 2))
    predicted = mixture.most_probable()
    holds = rests.sum(-1) > 0
    holding = Holding(rests, holds, belief + carried)
    predicted = torch.where((unseen & holds)[..., None], holding.state, predicted)
    return predicted, mixture, holding


def carry_held(
    predicted: torch.Tensor, holding: Holding, given: torch.Tensor, seen: torch.Tensor
) -> torch.Tensor:
    """Where the slots not ``given`` at frame t are [B, S, 13]: held ones where they rest,
    moved on by what their support was ``seen`` to do beyond its own prediction."""
    hidden_now = (~given)[..., None]
    correction = ((seen[..., POSITION] - predicted[..., POSITION]) * given[..., None]).detach()
    carried = torch.einsum("bij,bjk->bik", holding.rests, correction) * hidden_now
    held = torch.where(holding.holds[..., None] & hidden_now, holding.state, predicted)
    return held + F.pad(carried, (0, STATE_SIZE - 3))
