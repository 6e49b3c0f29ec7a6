"""What each slot makes of the others: the features of a slot pair (``SlotPairs``), held per
slot rather than per pair, and the interaction network over them (``PairNetwork``), summed
over the other known slots (``messages``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

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

#: The image-box overlaps (along right, up, and both): the one part of a pair's features that
#: is neither slot's own value nor a difference of the two.
OVERLAPS = 3


def pair_feature_size(layout: StateLayout) -> int:
    """Pair features (``SlotPairs``): the other object's position, camera coordinates and
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
        + OVERLAPS
        + layout.orientation_size
        + SHAPES
    )


@dataclass
class SlotPairs:
    """The features [``pair_feature_size``] of slot j seen from slot i, for every pair, held as
    ``own`` [B, S, F] (slot i's part) + ``other`` [B, S, F] (slot j's part) + ``overlaps``
    [B, S, S, 3] at columns ``overlap_columns`` (None where there are no image boxes, so no
    overlap). Each feature but the overlaps is one slot's value or a difference of two, so a
    linear layer over the pairs is a layer over each slot's part plus the overlaps' (``project``):
    the S x S pair features themselves are never built in a rollout."""

    own: torch.Tensor
    other: torch.Tensor
    overlaps: torch.Tensor | None
    overlap_columns: slice

    def full(self) -> torch.Tensor:
        """The pair features [B, S_i, S_j, F], built (for tests and reading)."""
        features = pairwise(self.own, self.other, None)
        if self.overlaps is None:
            return features
        before = self.overlap_columns.start
        after = features.shape[-1] - self.overlap_columns.stop
        return features + F.pad(self.overlaps, (before, after))

    def project(
        self, weight: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """A linear map ``weight`` [H, F] of the pair features, in its parts: per own slot i
        [B, S, H], per other slot j [B, S, H] and per pair [B, S, S, H] (None: no overlaps)."""
        overlaps = None
        if self.overlaps is not None:
            overlaps = F.linear(self.overlaps, weight[:, self.overlap_columns])
        return F.linear(self.own, weight), F.linear(self.other, weight), overlaps


def pairwise(own: torch.Tensor, other: torch.Tensor, pairs: torch.Tensor | None) -> torch.Tensor:
    """own_i + other_j (+ pairs_ij) [B, S_i, S_j, H] from ``SlotPairs.project``'s parts."""
    summed = own[:, :, None] + other[:, None]
    return summed if pairs is None else summed + pairs


def slot_pairs(
    state: torch.Tensor,
    shape: torch.Tensor,
    seen_as: torch.Tensor,
    layout: StateLayout,
    boxes: bool = True,
) -> SlotPairs:
    """The ``SlotPairs`` of slots with states laid out as ``layout`` says, their shapes and how
    each is seen (``seen_as``: its ``view``). Without ``boxes`` (no image-plane projection:
    ``seen_as`` is zero) every overlap is zero and none is computed."""
    centre, half = seen_as[..., BOX_CENTRE], seen_as[..., BOX_HALF]
    differences = torch.cat([state[..., layout.position], seen_as[..., CAMERA_XYZ], centre], -1)
    extent, zeros = state[..., layout.extent], state.new_zeros(*state.shape[:-1], OVERLAPS)
    turned = [] if layout.orientation is None else [state[..., layout.orientation]]
    no_orientation = [] if layout.orientation is None else [torch.zeros_like(turned[0])]
    own = torch.cat(
        [
            -differences,
            torch.zeros_like(extent),
            extent,
            torch.zeros_like(half),
            half,
            zeros,
            *no_orientation,
            torch.zeros_like(shape),
        ],
        dim=-1,
    )
    other = torch.cat(
        [differences, extent, torch.zeros_like(extent), half, torch.zeros_like(half), zeros]
        + turned
        + [shape],
        dim=-1,
    )
    start = differences.shape[-1] + 2 * extent.shape[-1] + 2 * half.shape[-1]
    columns = slice(start, start + OVERLAPS)
    if not boxes:
        return SlotPairs(own, other, None, columns)
    # the share of i's image box along right and up that j's spans
    own_half, gap = half[:, :, None], (centre[:, None, :] - centre[:, :, None]).abs()
    overlap = ((half[:, None] + own_half - gap) / (2 * own_half).clamp(min=1e-3)).clamp(0, 1)
    return SlotPairs(own, other, torch.cat([overlap, overlap.prod(-1, keepdim=True)], -1), columns)


def pair_weight(known: torch.Tensor) -> torch.Tensor:
    """1 for pairs (i, j) of known slots with j != i [B, S, S, 1]."""
    weight = known[:, None, :] & known[:, :, None]
    eye = torch.eye(known.shape[1], dtype=torch.bool, device=known.device)
    return (weight & ~eye).float()[..., None]


class PairNetwork(nn.Module):
    """An MLP over [own_i, other_j, pair_ij] for every slot pair, summed over j: its first layer
    split by input, so the slots' parts (and the pair features' per-slot parts, ``SlotPairs``)
    are computed once per slot, not once per pair, and its last (linear) layer applied once to
    each slot's sum, not to every pair (S times less each)."""

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
        pairs: SlotPairs,
        weight: torch.Tensor,
    ) -> torch.Tensor:
        """own [B, S, O], other [B, S, P] (or None), the pairs' features, each pair's weight
        [B, S, S, 1] -> sum over j of weight_ij * MLP(own_i, other_j, pair_ij) [B, S, out]."""
        own_part, other_part, overlaps = pairs.project(self.pair.weight)
        own_part = own_part + self.own(own)
        if self.other is not None:
            other_part = other_part + self.other(other)
        summed = (torch.relu(pairwise(own_part, other_part, overlaps)) * weight).sum(2)
        return F.linear(summed, self.out.weight) + self.out.bias * weight.sum(2)


def messages(
    network: PairNetwork,
    own: torch.Tensor,
    other: torch.Tensor | None,
    pairs: SlotPairs,
    known: torch.Tensor,
) -> torch.Tensor:
    """Sum over the other known slots j of network(own_i, other_j, pair_ij) [B, S, M]."""
    return cast(torch.Tensor, network(own, other, pairs, pair_weight(known)))
