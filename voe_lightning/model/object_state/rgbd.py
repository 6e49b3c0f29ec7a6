"""The RGB-D rung of the learner's perception: what a depth camera and a tracker give, with no 3D
box. Per frame and visible mask id, the mask rung's measures of its pixels (``masks.py``: the
image-plane centroid and half-extents, the area, the mean colour) and the record's ``depth``
measures of the same pixels (``specs.depth_spec``): their mean depth along the view axis, their
least depth and the share of the id's outline that a nearer surface (or the frame's edge) cuts.
Each is a function of frame t's image, depth image and mask alone; no shape label, no amodal
state. The depth as a whole is kept by measurement: with it the rung passes 3, 2 and 3 of 5 at
three seeds on a fresh set of stimuli version 14, object persistence and containment at two,
which the mask rung without any depth fails (docs/study/learned_physics.md). Its parts are not:
on 100 validation quadruplets of version 13, seed 0 passes 2 of 5 with the depth span and the
cut share (3 cm ``scenes.depth.CUT_MARGIN``), 3 without the span, 2 without the cut share
(``experiments/depth_ablation.py``); both are to go when the rung is next trained at three
seeds."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import torch

from voe_lightning.model.object_state.masks import MASKS, observe_measured, per_id
from voe_lightning.model.object_state.state import Observations, StateLayout, by_slot

#: An RGB-D-perceived state [cx, cy, mean depth, hx, hy, area, depth span, r, g, b, cut]:
#: what moves is the centroid (the mask rung's image plane) and the mean depth (m), so the
#: velocity holds the change in depth; how big it is, the pixels' half-extents, their area and
#: the depth span (mean less least depth: how far the seen surface reaches back); its mean
#: colour; last, the share of its outline a nearer surface or the frame's edge cuts, predicted
#: as the rest is.
RGBD = StateLayout(
    11, position=slice(0, 3), extent=slice(3, 7), color=slice(7, 10), orientation=None
)
#: Where the cut share lies in an ``RGBD`` state: the one part no named slice holds.
CUT = 10

#: The missing depth, in one line: what reads it and which records carry it.
NO_DEPTH = (
    "the object-state model with perception: rgbd reads each video's per-id depth measures "
    "(specs.depth_spec), but a batch came without {where}; records of stimuli version 13 or "
    "later (GENERATOR_VERSION 13) carry it"
)


def observe_rgbd(
    mask: torch.Tensor, frames: torch.Tensor, depth: torch.Tensor | None, camera: torch.Tensor
) -> Observations:
    """What the RGB-D rung reads of a batch of videos: per slot (a mask id, ordered as
    ``state.observe`` orders them) and frame, the ``RGBD`` state of its visible pixels, from
    ``mask`` [B, T, H, W], ``frames`` [B, T, H, W, 3] and ``depth`` [B, T, K, 3]; its area as
    the visible share, no shape and the camera poses. Frame t's observations read frame t
    alone. Without a ``depth`` (a batch that lacks it), a ValueError in one line."""
    if depth is None:
        raise ValueError(NO_DEPTH.format(where="batch key 'depth'"))
    return observe_rgbd_measured(per_id(mask, frames, depth), camera)


def observe_rgbd_measured(
    measured: Mapping[str, torch.Tensor], camera: torch.Tensor
) -> Observations:
    """``observe_rgbd`` from a batch's ``per_id`` measures made with its depth (held per clip,
    ``train_fields: [mask_features, camera]``, or made now): the mask rung's observations
    (``masks.observe_measured``) with each slot's depth measures laid into its state."""
    if "depth" not in measured:
        raise ValueError(NO_DEPTH.format(where="'depth' among its mask_features"))
    seen = observe_measured({k: v for k, v in measured.items() if k != "depth"}, camera)
    # zero where the id is not seen (``per_id``), as every other measure is
    mean, near, cut = by_slot(measured["depth"], seen.ids).unbind(-1)
    masks = seen.state
    state = torch.cat(
        [
            masks[..., MASKS.position],
            mean[..., None],
            masks[..., MASKS.extent],
            (mean - near)[..., None],
            masks[..., MASKS.color],
            cut[..., None],
        ],
        dim=-1,
    )
    return replace(seen, state=state)
