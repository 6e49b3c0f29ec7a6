"""Containment (paper §3, after Hespos & Baillargeon 2001): a cube falls into an open container,
a rod descends and slides the container sideways. Consistent: the cube travels inside it.
Inconsistent: the container slides away and reveals the cube, left behind.

Counterbalanced variant (ours): the cube falls behind the container (the
``cube_behind_container`` control). Consistent: the sliding container reveals it where it fell.
Inconsistent: it passed through the back wall while hidden and travels away inside the
container, never revealed. The two are one quadruplet per seed: one scene with the cube dropped
into the container (A) or just behind it (B), spliced at the last frame before the container
slides, so after it each inconsistent video is exactly the other variant's consistent one (the
standard inconsistent cube is revealed where B's lies, just behind where the back wall was)."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import cast

import mujoco
import numpy as np
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes import recording
from voe_lightning.scenes.appearance import distinct_colors
from voe_lightning.scenes.builder import SceneBuilder, yaw_quat
from voe_lightning.scenes.camera import CameraPose, CameraRange, VideoOptions, accept_any_video
from voe_lightning.scenes.container import container_geoms
from voe_lightning.scenes.sampling import RejectedSample, draw_until_valid, rng_for
from voe_lightning.scenes.simulation import Simulation, visible_ids

CONCEPT = "containment"
#: Its scenes render videos of any size and length (``scenes.check_video``).
check_video = accept_any_video
#: The one (static per clip) camera distribution of examples, every control and the probes.
CAMERA = CameraRange(
    lookat_x=(-0.2, 0.2),
    lookat_y=(0.0, 0.4),
    lookat_z=(0.3, 0.4),
    distance=(3.0, 3.8),
    azimuth=(75.0, 105.0),
    elevation=(-32.0, -22.0),
)
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


def smoothstep(x: float) -> float:
    """0 before 0, 1 after 1, a cosine ease in between (starts and stops at rest); the
    container's speed is its derivative."""
    x = min(max(x, 0.0), 1.0)
    return cast(float, 0.5 - 0.5 * np.cos(np.pi * x))


def build(
    rng: np.random.Generator, video: VideoOptions, camera: CameraPose, layout: Layout
) -> Simulation:
    """Compile the scene. The container is a heavy body on a slide joint along x whose velocity
    a per-step controller prescribes, so its walls and bottom carry the cube by contact and
    friction; the rod (a mocap body) comes down onto its trailing wall and rides along."""
    builder = SceneBuilder(rng, video, camera)
    container_color, cube_color, rod_color = distinct_colors(rng, 3)
    x0, y0 = layout.container_xy
    builder.add(
        "container",
        container_geoms(layout.half_x, layout.half_y, layout.height, WALL),
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
        quat=yaw_quat(layout.cube_yaw),
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


def timeline(
    rng: np.random.Generator, video: VideoOptions
) -> tuple[int, float, float, tuple[float, float]]:
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


@dataclass(frozen=True)
class LayoutRanges:
    """Uniform (low, high) ranges of a scene's free parameters: the container's inner
    half-sizes and wall height, the cube's half-size, the container's offset from the centre of
    its slide (``offset_x``, so the slide stays in view) and its depth ``y``, the slide's length
    (either direction) and how far above the rim the cube is dropped."""

    half_x: tuple[float, float]
    half_y: tuple[float, float]
    height: tuple[float, float]
    cube_half: tuple[float, float]
    offset_x: tuple[float, float]
    y: tuple[float, float]
    shift: tuple[float, float]
    drop: tuple[float, float]

    def contains(self, other: LayoutRanges) -> bool:
        """Whether every range of ``other`` lies inside this one's."""
        return all(
            getattr(self, f.name)[0] <= getattr(other, f.name)[0]
            and getattr(other, f.name)[1] <= getattr(self, f.name)[1]
            for f in fields(self)
        )


#: Probes (and the ``cube_behind_container`` control, which needs the same occlusion): a
#: container tall and wide enough to hide the cube lying on its bottom or just behind it, at
#: one depth range for both variants, so that the container and rod fill as many pixels in
#: every probe video and only the cube tells the videos apart (docs/calibration.md: a variant
#: whose container stood nearer the camera showed more of every cue in both its videos).
PROBE_RANGES = LayoutRanges(
    half_x=(0.26, 0.36),
    half_y=(0.2, 0.28),
    height=(0.42, 0.55),
    cube_half=(0.075, 0.1),
    offset_x=(-0.15, 0.15),
    y=(-0.35, -0.05),
    shift=(0.8, 1.1),
    drop=(0.35, 0.8),
)
#: The ``cube_behind_container`` control's cube falls behind the container: a larger cube
#: (revealed farther from the camera, and later, it would show fewer pixels than a probe's).
#: The probes' quadruplets drop one cube of PROBE_RANGES into or behind the container.
BEHIND_RANGES = replace(PROBE_RANGES, cube_half=(0.09, 0.12))
#: Examples (and ``cube_random_position``): "like probes, but container position and size are
#: not constrained to occlude the cube" (paper §3); every probe range lies well inside.
EXAMPLE_RANGES = LayoutRanges(
    half_x=(0.18, 0.45),
    half_y=(0.15, 0.4),
    height=(0.12, 0.7),
    cube_half=(0.06, 0.16),
    offset_x=(-0.45, 0.45),
    y=(-0.5, 0.6),
    shift=(0.7, 1.2),
    drop=(0.3, 0.9),
)


def sample_layout(
    rng: np.random.Generator, video: VideoOptions, ranges: LayoutRanges
) -> tuple[Layout, int]:
    """A layout drawn from ``ranges`` with the cube dropped into the container, and the
    manipulation frame (the last frame before the container slides)."""
    frame, move_start, move_end, rod_down = timeline(rng, video)

    def draw(name: str) -> float:
        return float(rng.uniform(*getattr(ranges, name)))

    half_x, half_y = draw("half_x"), draw("half_y")
    height, cube_half = draw("height"), draw("cube_half")
    shift = float(rng.choice([-1.0, 1.0])) * draw("shift")
    x0, y0 = -shift / 2 + draw("offset_x"), draw("y")
    layout = Layout(
        container_xy=(x0, y0),
        half_x=half_x,
        half_y=half_y,
        height=height,
        cube_half=cube_half,
        cube_start=(x0, y0, height + draw("drop")),
        cube_yaw=float(rng.uniform(0, np.pi / 2)),
        shift=shift,
        rod_down=rod_down,
        move_start=move_start,
        move_end=move_end,
    )
    layout.cube_start = (*inside_point(rng, layout), layout.cube_start[2])
    return layout, frame


def inside_point(rng: np.random.Generator, layout: Layout) -> tuple[float, float]:
    """A random (x, y) where the cube (any yaw) fits inside the container without touching
    its walls."""
    x0, y0 = layout.container_xy
    room_x = max(layout.half_x - layout.cube_half * 1.5, 0.0)
    room_y = max(layout.half_y - layout.cube_half * 1.5, 0.0)
    return x0 + float(rng.uniform(-room_x, room_x)), y0 + float(rng.uniform(-room_y, room_y))


def drop_behind(rng: np.random.Generator, layout: Layout) -> None:
    """Move the cube's drop point to just behind the container's back wall (from the camera)."""
    x0, y0 = layout.container_xy
    behind = layout.half_y + WALL + layout.cube_half * 1.5 + float(rng.uniform(0.0, 0.08))
    room_x = layout.half_x - layout.cube_half
    x = x0 + float(rng.uniform(-room_x, room_x))
    layout.cube_start = (x, y0 + behind, layout.cube_start[2])


def check_hidden_and_carried(
    sim: Simulation,
    layout: Layout,
    frame: int,
    videos: Sequence[recording.Video],
    start: tuple[float, float, float],
) -> None:
    """Reject a probe whose cube shows at the manipulation frame in either of its ``videos``,
    or whose cube ``sim`` (the branch where it rides in the container, run to the end) did not
    carry along with the container from ``start``."""
    cube = sim.mask_id("cube")
    for _, masks, _ in videos:
        if cube in visible_ids(masks[frame]):
            raise RejectedSample("the cube shows at the manipulation frame")
    carried = sim.position("cube")[0] - start[0]
    if abs(carried - layout.shift) > 0.6 * layout.half_x:
        raise RejectedSample(f"the cube moved {carried:.2f}, its container {layout.shift:.2f}")


def probe(variant: str, seed: int, video: VideoOptions) -> TensorDict:
    """A probe pair of ``variant``, one half of the seed's quadruplet (``quadruplet``):
    ``standard`` (the cube falls into the container; consistent: carried away, inconsistent:
    revealed behind it) or ``counterbalanced`` (it falls behind; consistent: revealed,
    inconsistent: carried away inside, never revealed)."""
    specs.check_variant(CONCEPT, variant)
    return recording.quadruplet_record(CONCEPT, variant, seed, quadruplet(seed, video))


@functools.lru_cache(maxsize=4)
def quadruplet(seed: int, video: VideoOptions) -> recording.Quadruplet:
    """One scene draw's quadruplet ((A, AB), (B, BA)): one container, rod and slide, the cube
    dropped into the container (A: it travels inside, hidden) or just behind it (B: the
    sliding container reveals it), both hidden at the manipulation frame, the last before the
    container slides (``recording.quadruplet``); with the camera, that frame and the cube's
    mask id. Cached, as both variants of a seed read it (callers copy what they keep)."""

    def make(rng: np.random.Generator) -> recording.Quadruplet:
        camera = CAMERA.sample(rng)
        inside, frame = sample_layout(rng, video, PROBE_RANGES)
        behind = replace(inside)
        drop_behind(rng, behind)
        scene_seed = int(rng.integers(2**63))  # one draw of colours for both scenes
        sims = [
            build(np.random.default_rng(scene_seed), video, camera, layout)
            for layout in (inside, behind)
        ]
        videos = [sim.record(video.num_frames) for sim in sims]
        check_hidden_and_carried(sims[0], inside, frame, videos, inside.cube_start)
        cube = sims[0].mask_id("cube")
        enough = MIN_VISIBLE_PIXELS * video.height * video.width / 4096
        if (videos[1][1][-1] == cube).sum() < enough:
            raise RejectedSample("the cube behind the container is not revealed")
        pairs = recording.quadruplet(videos[0], videos[1], frame)
        return pairs, camera.as_array(), frame, cube

    return draw_until_valid(make, rng_for(seed, CONCEPT, "quadruplet"))


def clip_layout(
    kind: str, rng: np.random.Generator, video: VideoOptions
) -> tuple[Layout, CameraPose, int]:
    """Layout, camera and the frame just before the container slides, for a training clip."""
    camera = CAMERA.sample(rng)
    if kind == "example":  # container size and place unconstrained: the cube may show
        layout, frame = sample_layout(rng, video, EXAMPLE_RANGES)
    elif kind == "cube_behind_container":  # lands just behind the back wall, hidden by it
        layout, frame = sample_layout(rng, video, BEHIND_RANGES)
        drop_behind(rng, layout)
    else:  # cube_random_position: anywhere in view, off the container's path, not behind it
        layout, frame = sample_layout(rng, video, EXAMPLE_RANGES)
        place_off_path(rng, layout)
    return layout, camera, frame


def place_off_path(rng: np.random.Generator, layout: Layout, draws: int = 100) -> None:
    """Drop the cube anywhere in view but off the container's slide and not behind it; a
    RejectedSample when ``draws`` positions all fall there (a wide container on a long slide
    can leave no room at all)."""
    x0, y0 = layout.container_xy
    clear_x = layout.half_x + WALL + 2 * layout.cube_half + 0.1
    clear_y = layout.half_y + WALL + 2 * layout.cube_half + 0.1
    swept = (min(x0, x0 + layout.shift) - clear_x, max(x0, x0 + layout.shift) + clear_x)
    for _ in range(draws):
        cx, cy = float(rng.uniform(-0.75, 0.75)), float(rng.uniform(-0.9, 0.8))
        in_path = abs(cy - y0) < clear_y and swept[0] < cx < swept[1]
        behind_it = cy > y0 and abs(cx - x0) < clear_x
        if not (in_path or behind_it):
            layout.cube_start = (cx, cy, float(rng.uniform(0.5, 1.2)))
            return
    raise RejectedSample(f"no place for the cube off the container's slide in {draws} draws")


def clip(kind: str, seed: int, video: VideoOptions) -> TensorDict:
    """A training clip: an ``example`` (cube into a container of any size and place, which is
    then slid), ``cube_behind_container`` (the cube lands hidden behind it and stays when it
    slides) or ``cube_random_position`` (the cube lands anywhere, the empty container slides)."""

    def draw_scene(rng: np.random.Generator) -> tuple[CameraPose, recording.Video]:
        layout, camera, frame = clip_layout(kind, rng, video)
        sim = build(rng, video, camera, layout)
        frames, masks, objects = sim.record(video.num_frames)
        cube = sim.mask_id("cube")
        if kind == "cube_behind_container" and cube in visible_ids(masks[frame]):
            raise RejectedSample("the cube behind the container is not hidden by it")
        enough = MIN_VISIBLE_PIXELS * video.height * video.width / 4096
        if kind == "cube_random_position" and (masks[frame] == cube).sum() < enough:
            raise RejectedSample("the randomly placed cube is hidden or out of view")
        return camera, (frames, masks, objects)

    return recording.draw_clip(CONCEPT, kind, seed, draw_scene)
