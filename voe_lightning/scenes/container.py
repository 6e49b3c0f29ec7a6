"""The open box that solidity and containment drop things into: its five geoms, and what its
outer box hides from a camera (an open box hides what lies behind it like a solid one)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from voe_lightning.scenes.builder import Geom


def container_geoms(half_x: float, half_y: float, height: float, wall: float) -> list[Geom]:
    """An open box: a bottom and four walls ``wall`` thick (inner half-sizes ``half_x`` x
    ``half_y``, outer height ``height``), its bottom's centre at the body's origin."""
    outer_x, outer_y, half_z = half_x + wall, half_y + wall, height / 2
    return [
        Geom("box", (outer_x, outer_y, wall / 2), (0.0, 0.0, wall / 2)),
        Geom("box", (outer_x, wall / 2, half_z), (0.0, -half_y - wall / 2, half_z)),
        Geom("box", (outer_x, wall / 2, half_z), (0.0, half_y + wall / 2, half_z)),
        Geom("box", (wall / 2, half_y, half_z), (-half_x - wall / 2, 0.0, half_z)),
        Geom("box", (wall / 2, half_y, half_z), (half_x + wall / 2, 0.0, half_z)),
    ]


def outer_gap(outer: tuple[float, float], xy: Sequence[float] | np.ndarray) -> float:
    """Distance from ``xy`` to a container's footprint of outer half-sizes ``outer`` centred at
    the origin (0 inside it)."""
    return float(np.hypot(max(abs(xy[0]) - outer[0], 0.0), max(abs(xy[1]) - outer[1], 0.0)))


def hides(
    eye: np.ndarray, outer: tuple[float, float], height: float, points: np.ndarray, margin: float
) -> bool:
    """Whether the segment from ``eye`` to every point [N, 3] passes through the container's
    outer box (half-sizes ``outer``, ``height`` tall, centred at the origin; shrunk by
    ``margin``)."""
    half = np.array(outer) - margin
    low = np.array([-half[0], -half[1], 0.0])
    high = np.array([half[0], half[1], height - margin])
    for point in points:
        direction = point - eye
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (low - eye) / direction, (high - eye) / direction
        near = np.nanmax(np.minimum(t1, t2))
        far = np.nanmin(np.maximum(t1, t2))
        if not (near <= far and 0.0 < far and near < 1.0):
            return False
    return True
