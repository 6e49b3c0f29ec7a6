"""What each slot makes of the others: the features of a slot pair (``pair_features``) and the
interaction network over them (``PairNetwork``), summed over the other known slots
(``messages``)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from voe_lightning.model.object_state.state import (
    BOX_CENTRE,
    BOX_HALF,
    CAMERA_XYZ,
    SHAPES,
    StateLayout,
)


def pair_feature_size(layout: StateLayout) -> int:
    """Pair features (``pair_features``): the other object's position, camera coordinates and
    image-box centre relative to this one's, both extents, both image-box half-extents, how
    much of this one's image box the other's covers (along right, up, and both), the other's
    orientation (where perception gives one) and shape."""
    return (
        layout.position_size
        + 3
        + 2
        + 2 * layout.extent_size
        + 2
        + 2
        + 3
        + layout.orientation_size
        + SHAPES
    )


def pair_features(
    state: torch.Tensor, shape: torch.Tensor, seen_as: torch.Tensor, layout: StateLayout
) -> torch.Tensor:
    """Pair features [B, S_i, S_j, ``pair_feature_size``] of slot j seen from slot i
    (``seen_as``: each slot's ``view``), from states laid out as ``layout`` says."""
    slots = state.shape[1]

    def other_minus_self(values):
        return values[:, None, :] - values[:, :, None]

    def other(values):
        return values[:, None].expand(-1, slots, -1, -1)

    def own(values):
        return values[:, :, None].expand(-1, -1, slots, -1)

    centre, half = seen_as[..., BOX_CENTRE], seen_as[..., BOX_HALF]
    # the share of i's image box along right and up that j's spans
    overlap = (
        (other(half) + own(half) - other_minus_self(centre).abs()) / (2 * own(half)).clamp(min=1e-3)
    ).clamp(0, 1)
    turned = [] if layout.orientation is None else [other(state[..., layout.orientation])]
    return torch.cat(
        [
            other_minus_self(state[..., layout.position]),
            other_minus_self(seen_as[..., CAMERA_XYZ]),
            other_minus_self(centre),
            other(state[..., layout.extent]),
            own(state[..., layout.extent]),
            other(half),
            own(half),
            overlap,
            overlap.prod(-1, keepdim=True),
            *turned,
            other(shape),
        ],
        dim=-1,
    )


def pair_weight(known: torch.Tensor) -> torch.Tensor:
    """1 for pairs (i, j) of known slots with j != i [B, S, S, 1]."""
    weight = known[:, None, :] & known[:, :, None]
    eye = torch.eye(known.shape[1], dtype=torch.bool, device=known.device)
    return (weight & ~eye).float()[..., None]


class PairNetwork(nn.Module):
    """An MLP over [own_i, other_j, pair_ij] for every slot pair, summed over j: its first layer
    split by input, so the slots' parts are computed once per slot, not once per pair, and its
    last (linear) layer applied once to each slot's sum, not to every pair (S times less each)."""

    def __init__(
        self, own_size: int, other_size: int, pair_size: int, hidden_size: int, output_size: int
    ):
        super().__init__()
        self.own = nn.Linear(own_size, hidden_size)
        self.other = nn.Linear(other_size, hidden_size, bias=False) if other_size else None
        self.pair = nn.Linear(pair_size, hidden_size, bias=False)
        self.out = nn.Linear(hidden_size, output_size)

    def forward(
        self,
        own: torch.Tensor,
        other: torch.Tensor | None,
        pairs: torch.Tensor,
        weight: torch.Tensor,
    ) -> torch.Tensor:
        """own [B, S, O], other [B, S, P] (or None), pairs [B, S, S, F], each pair's weight
        [B, S, S, 1] -> sum over j of weight_ij * MLP(own_i, other_j, pair_ij) [B, S, out]."""
        first = self.own(own)[:, :, None] + self.pair(pairs)
        if self.other is not None:
            first = first + self.other(other)[:, None]
        summed = (torch.relu(first) * weight).sum(2)
        return F.linear(summed, self.out.weight) + self.out.bias * weight.sum(2)


def messages(
    network: PairNetwork,
    own: torch.Tensor,
    other: torch.Tensor | None,
    pairs: torch.Tensor,
    known: torch.Tensor,
) -> torch.Tensor:
    """Sum over the other known slots j of network(own_i, other_j, pair_ij) [B, S, M]."""
    return network(own, other, pairs, pair_weight(known))
