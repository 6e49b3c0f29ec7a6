"""The mask rung of the learner's perception: what a camera and a tracker give, with no 3D state.
Per frame and visible mask id, measured from the record's ``mask`` and ``frames`` alone
(``observe_masks``): the image-plane centroid and half-extents of its pixels, its area (share of
the frame) and its mean colour. ``per_id`` also carries a record's ``depth`` measures where it is
given them, which the RGB-D rung reads (``rgbd.py``)."""

from __future__ import annotations

from collections.abc import Mapping

import torch

from voe_lightning import specs
from voe_lightning.model.object_state.geometry import paint_ellipses
from voe_lightning.model.object_state.state import (
    SHAPES,
    Observations,
    StateLayout,
    by_slot,
    slot_ids,
)

#: A mask-perceived state: centroid (x right, y up, the image plane's [-1, 1] across the height,
#: as ``geometry.view``'s image box), half-extents of the pixels' box, area, mean colour (RGB).
MASKS = StateLayout(
    8, position=slice(0, 2), extent=slice(2, 5), color=slice(5, 8), orientation=None
)


def seen_box(state: torch.Tensor, layout: StateLayout = MASKS) -> torch.Tensor:
    """The ``view`` of mask-perceived states [..., ``layout.size``] (``MASKS``, or the RGB-D
    rung's ``rgbd.RGBD``; ``geometry.VIEW`` wide): no camera coordinates (zeros), and the image
    box the pixels span (the position's and the extent's first two), as seen or believed."""
    centre, half = state[..., layout.position][..., :2], state[..., layout.extent][..., :2]
    return torch.cat([torch.zeros_like(state[..., :3]), centre, half], dim=-1)


def paint_boxes(
    belief: torch.Tensor, opacity: torch.Tensor, layout: StateLayout, image_size: tuple[int, int]
) -> torch.Tensor:
    """``geometry.paint_ellipses`` of mask-perceived states [B, T, S, ``layout.size``]
    (``MASKS``, or ``rgbd.RGBD``): an ellipse in each box the pixels span, in their colour,
    painted far to near: by the mean depth where the position holds one (RGB-D), else the
    larger area first."""
    centre, half = belief[..., layout.position][..., :2], belief[..., layout.extent][..., :2]
    holds_depth = layout.position_size == 3
    far = (
        belief[..., layout.position][..., 2] if holds_depth else belief[..., layout.extent][..., 2]
    )
    return paint_ellipses(centre, half, belief[..., layout.color], opacity, far, image_size)


def pixel_coordinates(height: int, width: int, device: torch.device) -> torch.Tensor:
    """Each pixel's centre on the image plane [H * W, 2] (x right, y up), row by row, in units
    of half the image's height (``geometry.image_plane``'s)."""
    focal = height / 2
    x = (torch.arange(width, device=device, dtype=torch.float32) + 0.5 - width / 2) / focal
    y = (height / 2 - torch.arange(height, device=device, dtype=torch.float32) - 0.5) / focal
    return torch.stack([x.repeat(height), y.repeat_interleave(width)], dim=-1)


def per_id(
    mask: torch.Tensor, frames: torch.Tensor, depth: torch.Tensor | None = None
) -> dict[str, torch.Tensor]:
    """Per frame and mask id [B, T, K, ...]: ``pixels`` (count), the pixels' ``centroid`` and
    half-extents (``half``, half a pixel at least), ``area`` and mean ``colour``, from ``mask``
    uint8 [B, T, H, W] and ``frames`` uint8 [B, T, H, W, 3]; zeros for an id not in the frame.
    Given a record's ``depth`` [B, T, K, 3] (``specs.depth_spec``: per id its visible pixels'
    mean and least depth and the share of its outline a nearer surface cuts), also ``depth``,
    float32 and zero where the mask shows no pixel of the id."""
    batch, steps, height, width = mask.shape
    count = specs.OBJECT_SLOTS
    ids = mask.long().flatten(2)  # [B, T, P]
    if int(ids.max()) >= count:
        raise ValueError(f"mask ids must be < {count} (specs.OBJECT_SLOTS), got {int(ids.max())}")
    xy = pixel_coordinates(height, width, mask.device).expand(batch, steps, -1, -1)
    colour = frames.flatten(2, 3).float() / 255.0  # [B, T, P, 3]
    values = torch.cat([torch.ones_like(xy[..., :1]), xy, colour], dim=-1)  # [B, T, P, 6]
    sums = values.new_zeros(batch, steps, count, 6).scatter_add_(
        2, ids[..., None].expand(-1, -1, -1, 6), values
    )
    pixels = sums[..., 0]
    seen = (pixels > 0)[..., None]
    mean = sums[..., 1:] / pixels.clamp(min=1)[..., None]
    index = ids[..., None].expand(-1, -1, -1, 2)
    low = xy.new_full((batch, steps, count, 2), torch.inf).scatter_reduce(2, index, xy, "amin")
    high = xy.new_full((batch, steps, count, 2), -torch.inf).scatter_reduce(2, index, xy, "amax")
    half_pixel = 1 / height  # a pixel spans 2 / height of the image plane
    half = torch.where(seen, (high - low) / 2 + half_pixel, 0.0)
    measures = {
        "pixels": pixels,
        "centroid": mean[..., :2] * seen,
        "half": half,
        "area": pixels / (height * width),
        "colour": mean[..., 2:] * seen,
    }
    if depth is not None:
        if tuple(depth.shape) != (batch, steps, count, len(specs.DEPTH_MEASURES)):
            raise ValueError(
                f"depth must be [B, T, {count}, {len(specs.DEPTH_MEASURES)}] (specs.depth_spec, batched) "
                f"for a mask {tuple(mask.shape)}, got {tuple(depth.shape)}"
            )
        measures["depth"] = depth.to(mask.device, torch.float32) * seen
    return measures


def observe_masks(mask: torch.Tensor, frames: torch.Tensor, camera: torch.Tensor) -> Observations:
    """What the mask rung reads of a batch of videos: per slot (a mask id, ordered as
    ``state.observe`` orders them) and frame, the ``MASKS`` state of its visible pixels, its
    area as the visible share, no shape (perception gives no label: the shape terms read
    nothing) and the camera poses. Frame t's observations read frame t alone."""
    return observe_measured(per_id(mask, frames), camera)


def observe_measured(measured: Mapping[str, torch.Tensor], camera: torch.Tensor) -> Observations:
    """``observe_masks`` from a batch's ``per_id`` measures, made once per clip and held
    (``train_fields: [mask_features, camera]``) or made now: the same observations."""
    ids = slot_ids(measured["pixels"] > 0)
    picked = {name: by_slot(value, ids) for name, value in measured.items()}
    visible = picked["pixels"] > 0
    state = torch.cat(
        [picked["centroid"], picked["half"], picked["area"][..., None], picked["colour"]], dim=-1
    )
    return Observations(
        ids=ids,
        state=state,
        shape=state.new_zeros(*visible.shape, SHAPES),
        fraction=picked["area"],
        visible=visible,
        camera=camera.float(),
    )
