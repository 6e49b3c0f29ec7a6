"""What a depth camera shows of each object: per mask id and frame, measured from the rendered
depth image over the id's visible pixels alone (``depth_measures``), so a function of that
frame's depth and mask, as an RGB-D camera and a tracker give it."""

from __future__ import annotations

import numpy as np

from voe_lightning import specs

#: A surface counts as in front of an object's outline when it is nearer by more than this (m):
#: beyond the depth buffer's noise, below the gap between a screen and what it hides.
CUT_MARGIN = 0.03


def depth_measures(mask: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Per mask id [OBJECT_SLOTS, 3] (``specs.DEPTH_MEASURES``), from ``mask`` uint8 [H, W]
    and ``depth`` [H, W] (m along the view axis): the mean and the least depth of the id's
    pixels, and the share of its outline (its pixels with a 4-neighbour of another id, or on
    the frame's edge) where the frame ends or another object's surface is nearer by more than
    ``CUT_MARGIN``: how much of what shows of it something in front may hide. Zero for an id
    not seen, and for id 0 (the floor and fixed scenery), whose own edges cut nothing."""
    count = specs.OBJECT_SLOTS
    ids = mask.astype(np.int64)
    flat, values = ids.ravel(), depth.astype(np.float64).ravel()
    pixels = np.bincount(flat, minlength=count)
    mean = np.bincount(flat, weights=values, minlength=count) / np.maximum(pixels, 1)
    near = np.full(count, np.inf)
    np.minimum.at(near, flat, values)
    outline, cut = np.zeros(ids.shape, bool), np.zeros(ids.shape, bool)
    padded_ids = np.pad(ids, 1, constant_values=-1)  # -1: beyond the frame's edge
    padded_depth = np.pad(depth.astype(np.float64), 1, constant_values=-np.inf)
    height, width = ids.shape
    for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        other = padded_ids[1 + dy : 1 + dy + height, 1 + dx : 1 + dx + width]
        other_depth = padded_depth[1 + dy : 1 + dy + height, 1 + dx : 1 + dx + width]
        border = other != ids
        outline |= border
        cut |= border & ((other == -1) | ((other > 0) & (other_depth < depth - CUT_MARGIN)))
    outlined = np.bincount(flat, weights=outline.ravel(), minlength=count)
    share = np.bincount(flat, weights=cut.ravel(), minlength=count) / np.maximum(outlined, 1)
    measures = np.stack([mean, near, share], axis=-1)
    measures[pixels == 0] = 0.0
    measures[0] = 0.0
    return measures.astype(np.float32)
