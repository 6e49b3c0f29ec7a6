"""What an object looks like: its primitive shapes (MuJoCo geom types and the ``objects/shape_label``
each records) and the palette of distinct colours scenes draw from."""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from voe_lightning import specs

SHAPES = {
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
    "ellipsoid": mujoco.mjtGeom.mjGEOM_ELLIPSOID,
}
#: ``objects/shape_label`` of an object of one geom, by MuJoCo geom type.
SHAPE_LABELS = {
    int(geom_type): specs.OBJECT_SHAPES.index(name) for name, geom_type in SHAPES.items()
}

#: Distinct, saturated object colours (the paper's figures use such colours on a plain floor).
PALETTE: dict[str, tuple[float, float, float]] = {
    "red": (0.90, 0.15, 0.15),
    "green": (0.15, 0.75, 0.20),
    "blue": (0.15, 0.35, 0.95),
    "yellow": (0.95, 0.85, 0.10),
    "magenta": (0.90, 0.20, 0.85),
    "cyan": (0.10, 0.85, 0.90),
    "orange": (0.98, 0.55, 0.10),
    "purple": (0.55, 0.25, 0.85),
    "white": (0.95, 0.95, 0.95),
    "pink": (0.98, 0.60, 0.70),
}
COLOR_NAMES: tuple[str, ...] = tuple(PALETTE)


def rgba(color: str | Sequence[float], alpha: float = 1.0) -> list[float]:
    """An RGBA list from a palette name or an RGB triple."""
    rgb = PALETTE[color] if isinstance(color, str) else color
    return [*rgb, alpha]


def distinct_colors(rng: np.random.Generator, count: int) -> tuple[str, ...]:
    """``count`` different palette colour names, drawn at random."""
    return tuple(COLOR_NAMES[i] for i in rng.choice(len(COLOR_NAMES), size=count, replace=False))
