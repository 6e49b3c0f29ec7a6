"""Containment (paper §3, after Hespos & Baillargeon 2001): a cube falls into an open container,
a rod descends and slides the container sideways. Consistent: the cube travels inside it.
Inconsistent: the container slides away and reveals the cube where it fell."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes import base
from voe_lightning.scenes.base import (
    CameraPose,
    Geom,
    RejectedSample,
    SceneBuilder,
    Simulation,
    VideoOptions,
)

CONCEPT = "containment"
#: Probes use one static camera looking down on the container just enough to see its rim.
PROBE_CAMERA = CameraPose(lookat=(0.0, 0.2, 0.35), distance=3.0, azimuth=90.0, elevation=-27.0)
WALL = 0.03  # wall and bottom thickness of the container
ROD_RADIUS = 0.035
ROD_HALF_LENGTH = 0.8
ROD_START_HEIGHT = 3.2  # the rod's lower end starts above the top of the view
#: The container is heavy enough that the cube's push does not slow it (velocity-driven).
CONTAINER_DENSITY = 50_000.0
#: A cube meant to be seen shows at least this many pixels in a 64x64 frame (scaled by area).
MIN_VISIBLE_PIXELS = 10


@dataclass
class Layout:
    """One containment scene. The container (inner half-sizes ``half_x``, ``half_y``, wall
    ``height``) stands at ``container_xy``; the cube (half-size ``cube_half``) drops from
    ``cube_start``; the rod lands on the trailing wall, then both slide by ``shift`` along x
    between ``move_start`` and ``move_end`` seconds."""

    container_xy: tuple[float, float]
    half_x: float
    half_y: float
    height: float
    cube_half: float
    cube_start: tuple[float, float, float]
    cube_yaw: float
    shift: float
    rod_down: tuple[float, float]
    move_start: float
    move_end: float


def container_geoms(half_x: float, half_y: float, height: float) -> list[Geom]:
    """An open box: a bottom and four walls (inner half-sizes ``half_x`` x ``half_y``)."""
    outer_x, outer_y, half_z = half_x + WALL, half_y + WALL, height / 2
    return [
        Geom("box", (outer_x, outer_y, WALL / 2), (0.0, 0.0, WALL / 2)),
        Geom("box", (outer_x, WALL / 2, half_z), (0.0, -half_y - WALL / 2, half_z)),
        Geom("box", (outer_x, WALL / 2, half_z), (0.0, half_y + WALL / 2, half_z)),
        Geom("box", (WALL / 2, half_y, half_z), (-half_x - WALL / 2, 0.0, half_z)),
        Geom("box", (WALL / 2, half_y, half_z), (half_x + WALL / 2, 0.0, half_z)),
    ]


def smoothstep(x: float) -> float:
    """0 before 0, 1 after 1, a cosine ease in between (starts and stops at rest); the
    container's speed is its derivative."""
    x = min(max(x, 0.0), 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def build(
    rng: np.random.Generator, video: VideoOptions, camera: CameraPose, layout: Layout
) -> Simulation:
    """Compile the scene. The container is a heavy body on a slide joint along x whose velocity
    a per-step controller prescribes, so its walls and bottom carry the cube by contact and
    friction; the rod (a mocap body) comes down onto its trailing wall and rides along."""
    builder = SceneBuilder(rng, video, camera)
    container_color, cube_color, rod_color = rng.choice(base.COLOR_NAMES, size=3, replace=False)
    x0, y0 = layout.container_xy
    builder.add(
        "container",
        container_geoms(layout.half_x, layout.half_y, layout.height),
        (x0, y0, 0.0),
        container_color,
        free=False,
        density=CONTAINER_DENSITY,
    )
    builder.spec.body("container").add_joint(
        name="container_slide", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1.0, 0.0, 0.0]
    )
    builder.add_primitive(
        "cube",
        "box",
        (layout.cube_half,) * 3,
        layout.cube_start,
        cube_color,
        quat=base.yaw_quat(layout.cube_yaw),
    )
    rod_offset = -np.sign(layout.shift) * (layout.half_x + WALL / 2)
    rod_top = (x0 + rod_offset, y0, ROD_START_HEIGHT + ROD_HALF_LENGTH)
    builder.add_primitive(
        "rod", "cylinder", (ROD_RADIUS, ROD_HALF_LENGTH), rod_top, rod_color, free=False, mocap=True
    )
    sim = builder.build()
    # Collision bits: the floor is 1/1. The container (2/2) touches the cube (1/3) but not the
    # floor it slides over; the rod touches nothing.
    for geom_name in sim.objects["container"].geom_names:
        sim.model.geom(geom_name).contype = sim.model.geom(geom_name).conaffinity = 2
    for geom_name in sim.objects["cube"].geom_names:
        sim.model.geom(geom_name).conaffinity = 3
    for geom_name in sim.objects["rod"].geom_names:
        sim.model.geom(geom_name).contype = sim.model.geom(geom_name).conaffinity = 0
    slide = sim.model.joint("container_slide")
    slide_qpos, slide_dof = slide.qposadr[0], slide.dofadr[0]
    rod = sim.model.body("rod").mocapid[0]
    low = layout.height + ROD_HALF_LENGTH
    high = ROD_START_HEIGHT + ROD_HALF_LENGTH
    move_time = layout.move_end - layout.move_start

    def controller(sim: Simulation) -> None:
        time = sim.data.time
        progress = (time - layout.move_start) / move_time
        speed = 0.0
        if 0.0 < progress < 1.0:
            speed = layout.shift * 0.5 * np.pi / move_time * np.sin(np.pi * progress)
        sim.data.qvel[slide_dof] = speed
        down = smoothstep((time - layout.rod_down[0]) / (layout.rod_down[1] - layout.rod_down[0]))
        x = x0 + sim.data.qpos[slide_qpos] + rod_offset
        sim.data.mocap_pos[rod] = (x, y0, high + (low - high) * down)

    sim.controller = controller
    return sim


def release_cube(sim: Simulation) -> None:
    """The hidden 'magic': the container's walls and bottom no longer touch the cube, which
    drops onto the floor (by the bottom's thickness) and stays when the container slides away."""
    for geom_name in sim.objects["container"].geom_names:
        sim.model.geom(geom_name).contype = sim.model.geom(geom_name).conaffinity = 0


def timeline(rng: np.random.Generator, video: VideoOptions) -> tuple[int, float, float, tuple]:
    """Manipulation frame, move start and end (s), and rod descent (s): the rod comes down
    while the cube settles; the container starts sliding just after the manipulation frame."""
    frame_time = video.steps_per_frame * video.timestep
    total = video.num_frames * frame_time
    frame = int(rng.integers(round(0.45 * video.num_frames), round(0.55 * video.num_frames) + 1))
    frame = min(max(frame, 1), video.num_frames - 2)
    move_start = (frame + 0.5) * frame_time
    move_end = move_start + (total - move_start) * float(rng.uniform(0.7, 0.85))
    rod_down = (float(rng.uniform(0.05, 0.15)) * total, move_start - 0.3 * frame_time)
    return frame, move_start, move_end, rod_down


def probe_layout(rng: np.random.Generator, video: VideoOptions) -> tuple[Layout, int]:
    """A container tall enough to hide the cube lying on its bottom; the cube dropped into it."""
    frame, move_start, move_end, rod_down = timeline(rng, video)
    half_x, half_y = float(rng.uniform(0.26, 0.36)), float(rng.uniform(0.2, 0.28))
    cube_half = float(rng.uniform(0.08, 0.11))
    height = float(rng.uniform(0.42, 0.55))
    shift = float(rng.choice([-1.0, 1.0])) * float(rng.uniform(0.8, 1.1))
    x0 = -shift / 2 + float(rng.uniform(-0.15, 0.15))
    y0 = float(rng.uniform(-0.1, 0.2))
    room_x, room_y = half_x - cube_half * 1.5, half_y - cube_half * 1.5
    cube_start = (
        x0 + float(rng.uniform(-room_x, room_x)),
        y0 + float(rng.uniform(-room_y, room_y)),
        height + float(rng.uniform(0.35, 0.8)),
    )
    layout = Layout(
        container_xy=(x0, y0),
        half_x=half_x,
        half_y=half_y,
        height=height,
        cube_half=cube_half,
        cube_start=cube_start,
        cube_yaw=float(rng.uniform(0, np.pi / 2)),
        shift=shift,
        rod_down=rod_down,
        move_start=move_start,
        move_end=move_end,
    )
    return layout, frame


def probe(variant: str, seed: int, video: VideoOptions) -> TensorDict:
    """A consistent/inconsistent pair (variant ``standard``): both share the frames up to the
    one just before the container slides, where the cube lies hidden by its walls; from there
    the inconsistent twin's container no longer touches the cube."""
    specs.check_variant(CONCEPT, variant)

    def make(rng: np.random.Generator) -> TensorDict:
        layout, frame = probe_layout(rng, video)
        sim = build(rng, video, PROBE_CAMERA, layout)
        consistent, inconsistent = base.record_pair(sim, frame, release_cube)
        cube = sim.mask_id("cube")
        for _, masks in (consistent, inconsistent):
            if cube in base.visible_ids(masks[frame]):
                raise RejectedSample("the cube shows over the container's walls")
        carried = sim.position("cube")[0] - layout.cube_start[0]
        if abs(carried - layout.shift) > 0.6 * layout.half_x:
            raise RejectedSample(f"the cube moved {carried:.2f}, its container {layout.shift:.2f}")
        return base.probe_record(
            CONCEPT, variant, seed, consistent, inconsistent, PROBE_CAMERA, frame, [cube]
        )

    return base.draw_until_valid(make, base.rng_for(seed, CONCEPT, variant))


def example_camera(rng: np.random.Generator) -> CameraPose:
    """Training clips vary the (static) camera from video to video."""
    return CameraPose(
        lookat=(float(rng.uniform(-0.2, 0.2)), float(rng.uniform(0.0, 0.4)), 0.3),
        distance=float(rng.uniform(3.0, 3.8)),
        azimuth=float(rng.uniform(75.0, 105.0)),
        elevation=float(rng.uniform(-36.0, -24.0)),
    )


def clip_layout(
    kind: str, rng: np.random.Generator, video: VideoOptions
) -> tuple[Layout, CameraPose, int]:
    """Layout, camera and the frame just before the container slides, for a training clip."""
    layout, frame = probe_layout(rng, video)
    x0, y0 = layout.container_xy
    camera = PROBE_CAMERA
    if kind == "example":  # container size and place unconstrained: the cube may show
        camera = example_camera(rng)
        layout.half_x, layout.half_y = float(rng.uniform(0.18, 0.45)), float(rng.uniform(0.15, 0.4))
        layout.height = float(rng.uniform(0.12, 0.55))
        layout.cube_half = float(rng.uniform(0.06, 0.16))
        x0, y0 = x0 + float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-0.5, 0.6))
        layout.container_xy = (x0, y0)
        room_x = max(layout.half_x - layout.cube_half * 1.5, 0.0)
        room_y = max(layout.half_y - layout.cube_half * 1.5, 0.0)
        layout.cube_start = (
            x0 + float(rng.uniform(-room_x, room_x)),
            y0 + float(rng.uniform(-room_y, room_y)),
            layout.height + float(rng.uniform(0.35, 0.8)),
        )
    elif kind == "cube_behind_container":  # lands just behind the back wall
        behind = layout.half_y + WALL + layout.cube_half * 1.5 + float(rng.uniform(0.0, 0.15))
        room_x = layout.half_x - layout.cube_half
        layout.cube_start = (
            x0 + float(rng.uniform(-room_x, room_x)),
            y0 + behind,
            layout.cube_start[2],
        )
    else:  # cube_random_position: anywhere in view, off the container's path, not behind it
        clear_x = layout.half_x + WALL + 2 * layout.cube_half + 0.1
        clear_y = layout.half_y + WALL + 2 * layout.cube_half + 0.1
        swept = (min(x0, x0 + layout.shift) - clear_x, max(x0, x0 + layout.shift) + clear_x)
        while True:
            cx, cy = float(rng.uniform(-0.75, 0.75)), float(rng.uniform(-0.9, 0.8))
            in_path = abs(cy - y0) < clear_y and swept[0] < cx < swept[1]
            behind_it = cy > y0 and abs(cx - x0) < clear_x
            if not (in_path or behind_it):
                break
        layout.cube_start = (cx, cy, float(rng.uniform(0.5, 1.2)))
    return layout, camera, frame


def clip(kind: str, seed: int, video: VideoOptions) -> TensorDict:
    """A training clip: an ``example`` (cube into a container of any size and place, which is
    then slid), ``cube_behind_container`` (the cube lands hidden behind it and stays when it
    slides) or ``cube_random_position`` (the cube lands anywhere, the empty container slides)."""
    specs.check_kind(CONCEPT, kind)

    def make(rng: np.random.Generator) -> TensorDict:
        layout, camera, frame = clip_layout(kind, rng, video)
        sim = build(rng, video, camera, layout)
        frames, masks = sim.record(video.num_frames)
        cube = sim.mask_id("cube")
        if kind == "cube_behind_container" and cube in base.visible_ids(masks[frame]):
            raise RejectedSample("the cube behind the container is not hidden by it")
        enough = MIN_VISIBLE_PIXELS * video.height * video.width / 4096
        if kind == "cube_random_position" and (masks[frame] == cube).sum() < enough:
            raise RejectedSample("the randomly placed cube is hidden or out of view")
        return base.clip_record(CONCEPT, kind, seed, frames, masks, camera)

    return base.draw_until_valid(make, base.rng_for(seed, CONCEPT, kind))
