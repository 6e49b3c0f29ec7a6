"""Solidity (paper §3, after Hespos & Baillargeon 2001): a rectangular block is dropped into an
open container. In probes the camera sees inside the top of the container but not its bottom;
the consistent block comes to rest inside, the inconsistent one falls through the container
and the floor (its collisions switched off once inside), the penetration hidden by the front
face. Examples vary sizes and perspective freely; controls show the container alone, or the
block falling behind it."""

from __future__ import annotations

import numpy as np
from tensordict import TensorDict

from voe_lightning.scenes import base
from voe_lightning.scenes.base import CameraPose, Geom, RejectedSample, SceneBuilder, VideoOptions

CONCEPT = "solidity"
#: Pixels of the block that the inconsistent video may show beyond the consistent one (edges).
PENETRATION_TOLERANCE = 2


def _draw_container(rng: np.random.Generator) -> dict:
    """An open box: interior half width/depth, wall half thickness and outer height."""
    return {
        "inner_x": float(rng.uniform(0.35, 0.6)),
        "inner_y": float(rng.uniform(0.25, 0.4)),
        "wall": float(rng.uniform(0.025, 0.04)),
        "height": float(rng.uniform(0.55, 0.8)),
    }


def _add_container(builder: SceneBuilder, box: dict, color: str) -> None:
    """The container as one fixed object of five box geoms (bottom and four walls)."""
    ix, iy, w, h = box["inner_x"], box["inner_y"], box["wall"], box["height"]
    geoms = [
        Geom("box", (ix + 2 * w, iy + 2 * w, w), (0.0, 0.0, w)),
        Geom("box", (ix + 2 * w, w, h / 2), (0.0, -(iy + w), h / 2)),
        Geom("box", (ix + 2 * w, w, h / 2), (0.0, iy + w, h / 2)),
        Geom("box", (w, iy, h / 2), (-(ix + w), 0.0, h / 2)),
        Geom("box", (w, iy, h / 2), (ix + w, 0.0, h / 2)),
    ]
    builder.add("container", geoms, (0.0, 0.0, 0.0), color, free=False)


def _clear_of_container(box: dict, xy, radius: float) -> bool:
    """Whether a disc of ``radius`` at ``xy`` lies outside the container's outer walls."""
    outer_x, outer_y = box["inner_x"] + 2 * box["wall"], box["inner_y"] + 2 * box["wall"]
    gap = np.hypot(max(abs(xy[0]) - outer_x, 0.0), max(abs(xy[1]) - outer_y, 0.0))
    return bool(gap > radius)


def _draw_block(rng: np.random.Generator, box: dict, heights: tuple[float, float]) -> dict:
    """A block that fits inside the container upright, its height a random multiple (in
    ``heights``) of the container's inner depth, with a small random yaw."""
    depth = box["height"] - 2 * box["wall"]
    yaw = float(np.deg2rad(rng.uniform(-12, 12)))
    cos, sin = abs(np.cos(yaw)), abs(np.sin(yaw))
    while True:
        half_x = float(rng.uniform(0.08, 0.3))
        half_y = float(rng.uniform(0.08, 0.22))
        # Footprint of the yawed block, with room to spare on every side.
        reach_x, reach_y = half_x * cos + half_y * sin, half_x * sin + half_y * cos
        if reach_x <= box["inner_x"] - 0.06 and reach_y <= box["inner_y"] - 0.06:
            break
    offset = (
        float(rng.uniform(-1, 1) * (box["inner_x"] - 0.04 - reach_x)),
        float(rng.uniform(-1, 1) * (box["inner_y"] - 0.04 - reach_y)),
    )
    half_z = float(rng.uniform(*heights) * depth / 2)
    return {"half": (half_x, half_y, half_z), "yaw": yaw, "offset": offset}


def _add_block(builder: SceneBuilder, block: dict, xy, bottom: float, color: str) -> None:
    builder.add_primitive(
        "block",
        "box",
        block["half"],
        (xy[0], xy[1], bottom + block["half"][2]),
        color,
        quat=base.yaw_quat(block["yaw"]),
    )


def _colors(rng: np.random.Generator) -> tuple[str, str]:
    container, block = rng.choice(len(base.COLOR_NAMES), size=2, replace=False)
    return base.COLOR_NAMES[container], base.COLOR_NAMES[block]


def _block_bottom(sim: base.Simulation) -> float:
    return float(sim.position("block")[2] - sim.model.geom("block_0").size[2])


def _fall_through(twin: base.Simulation) -> None:
    """The magic: the block stops colliding, so it falls through the container and the floor."""
    for geom_name in twin.objects["block"].geom_names:
        twin.model.geom(geom_name).contype = 0
        twin.model.geom(geom_name).conaffinity = 0


def _probe_camera(rng: np.random.Generator, box: dict) -> CameraPose:
    """Perspective control: the line of sight over the front rim meets the back wall well above
    the inner bottom, so the camera sees inside the top of the container but never its bottom."""
    depth = box["height"] - 2 * box["wall"]
    steepest = np.rad2deg(np.arctan(0.6 * depth / (2 * box["inner_y"] + 2 * box["wall"])))
    return CameraPose(
        lookat=(0.0, 0.0, float(box["height"] * rng.uniform(0.8, 1.1))),
        distance=float(rng.uniform(2.4, 2.9)),
        azimuth=float(90 + rng.uniform(-5, 5)),
        elevation=-float(rng.uniform(min(12.0, steepest - 2), steepest)),
    )


def probe(variant: str, seed: int, video: VideoOptions) -> TensorDict:
    """The ``standard`` probe pair: the block rests in the container, or falls through it."""
    if variant != "standard":
        raise ValueError(f"unknown {CONCEPT} probe variant {variant!r}; valid: standard")
    rng = base.rng_for(seed, CONCEPT, variant)

    def make(rng: np.random.Generator) -> TensorDict:
        box = _draw_container(rng)
        block = _draw_block(rng, box, heights=(0.9, 1.7))
        camera = _probe_camera(rng, box)
        container_color, block_color = _colors(rng)
        builder = SceneBuilder(rng, video, camera)
        _add_container(builder, box, container_color)
        drop = box["height"] + rng.uniform(0.05, 0.3)
        _add_block(builder, block, block["offset"], drop, block_color)
        sim = builder.build()
        block_id = sim.mask_id("block")
        rim = box["height"] - 0.02

        def inside(sim: base.Simulation, frame: int) -> bool:
            return frame <= video.num_frames - 3 and _block_bottom(sim) < rim

        consistent, inconsistent, frame = base.record_pair_when(sim, _fall_through, inside)
        for t in range(frame, video.num_frames):
            extra = (inconsistent[1][t] == block_id) & (consistent[1][t] != block_id)
            if extra.sum() > PENETRATION_TOLERANCE:
                raise RejectedSample("the block's fall through the container shows")
        if (consistent[1][-1] == block_id).sum() < 6:
            raise RejectedSample("the resting block is hidden: the probe would show no difference")
        if block_id in base.visible_ids(inconsistent[1][-1]):
            raise RejectedSample("the falling block is still in view at the end")
        return base.probe_record(
            CONCEPT, variant, seed, consistent, inconsistent, camera, frame, [block_id]
        )

    return base.draw_until_valid(make, rng)


def clip(kind: str, seed: int, video: VideoOptions) -> TensorDict:
    """A training clip: ``example`` (a block of any height drops into the container, seen from
    any perspective), ``no_object`` (the container alone) or ``object_behind_container``."""
    kinds = ("example", "no_object", "object_behind_container")
    if kind not in kinds:
        raise ValueError(f"unknown {CONCEPT} clip kind {kind!r}; valid: {', '.join(kinds)}")
    rng = base.rng_for(seed, CONCEPT, kind)

    def make(rng: np.random.Generator) -> TensorDict:
        box = _draw_container(rng)
        block = _draw_block(rng, box, heights=(0.2, 1.5))
        camera = CameraPose(
            lookat=(0.0, 0.0, float(box["height"] * rng.uniform(0.4, 0.9))),
            distance=float(rng.uniform(2.4, 3.6)),
            azimuth=float(90 + rng.uniform(-40, 40)),
            elevation=-float(rng.uniform(12, 55)),
        )
        container_color, block_color = _colors(rng)
        builder = SceneBuilder(rng, video, camera)
        _add_container(builder, box, container_color)
        drop = box["height"] + rng.uniform(0.1, 0.6)
        if kind == "example":
            _add_block(builder, block, block["offset"], drop, block_color)
        elif kind == "object_behind_container":
            # Behind the container as the camera sees it: along the line of sight, just past
            # where the block's footprint clears the container.
            view = np.deg2rad(camera.azimuth)
            along = np.array([np.cos(view), np.sin(view)])
            across = np.array([-along[1], along[0]])
            start = along * box["inner_y"] + across * rng.uniform(-0.5, 0.5) * box["inner_x"]
            radius = float(np.hypot(*block["half"][:2]))
            behind = 0.0
            while not _clear_of_container(box, start + behind * along, radius):
                behind += 0.02
            xy = start + (behind + rng.uniform(0.05, 0.4)) * along
            _add_block(builder, block, xy, drop, block_color)
        sim = builder.build()
        frames, masks = sim.record(video.num_frames)
        if kind != "no_object" and sim.mask_id("block") not in base.visible_ids(masks[0]):
            raise RejectedSample("the block is not seen before it falls")
        return base.clip_record(CONCEPT, kind, seed, frames, masks, camera)

    return base.draw_until_valid(make, rng)
