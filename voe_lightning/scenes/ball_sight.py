"""Where a rendered ball shows in a video: its visible pixels per frame, what hides its centre, the
image column a point projects to, how many pixels its whole disc would cover, and whether it
touches the frame's edge (continuity's probes read each)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import numpy as np

from voe_lightning.scenes.camera import camera_axes, focal_length, pixel_of
from voe_lightning.scenes.simulation import Simulation


def ball_pixels(masks: np.ndarray, ball_id: int) -> np.ndarray:
    """Visible ball pixels per frame."""
    return cast(np.ndarray, (masks == ball_id).sum(axis=(1, 2)))


def what_hides_ball(sim: Simulation, masks: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Per frame, the mask id seen at the ball's centre (the ball's own id when it shows, an
    occluder's id when hidden, 0 for floor or -1 when its centre is outside the frame)."""
    video = sim.video
    seen = np.full(len(masks), -1)
    for t, position in enumerate(positions):
        row, column = pixel_of(sim.camera, video, position)
        if 0 <= row < video.height and 0 <= column < video.width:
            seen[t] = masks[t, row, column]
    return seen


def column(sim: Simulation, point: Sequence[float] | np.ndarray) -> int:
    """Image column of the world ``point``."""
    return pixel_of(sim.camera, sim.video, point)[1]


def full_ball_pixels(sim: Simulation, radius: float, y: float) -> float:
    """Roughly how many pixels a whole ball of ``radius`` at depth ``y`` covers."""
    position, _, _, forward = camera_axes(sim.camera)
    depth = (np.array([position[0], y, radius]) - position) @ forward
    return float(np.pi * (focal_length(sim.video) * radius / depth) ** 2)


def at_frame_edge(masks: np.ndarray, object_id: int) -> np.ndarray:
    """Per frame of ``masks`` [T, H, W], whether ``object_id`` shows in the frame's border
    pixels: part of it may lie outside the view."""
    shown = masks == object_id
    rows, columns = shown[:, [0, -1]].any((1, 2)), shown[:, :, [0, -1]].any((1, 2))
    edge: np.ndarray = rows | columns
    return edge
