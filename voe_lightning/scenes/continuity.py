"""Continuity (paper §3, after Aguilar & Baillargeon 1999): a ball rolls behind pillars. In the
inconsistent probe it vanishes behind the first pillar and reappears behind the last one without
ever crossing the gap; the ``gap_block`` control shows the same visibility pattern physically."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes import base
from voe_lightning.scenes.base import (
    CameraPose,
    RejectedSample,
    SceneBuilder,
    Simulation,
    VideoOptions,
)

CONCEPT = "continuity"
#: Probes use one static camera looking down on the pillars (mostly floor in view).
PROBE_CAMERA = CameraPose(lookat=(0.0, 0.3, 0.3), distance=3.8, azimuth=90.0, elevation=-26.0)
PILLAR_DEPTH = 0.12
#: A ball counts as seen in a gap when at least this share of its largest visible area shows.
VISIBLE_SHARE = 0.5


@dataclass
class Layout:
    """One continuity scene: pillars (centre x, width) in the plane y = 0, an optional block
    filling the gap between the outer two, and a ball launched rolling from ``ball_start``."""

    pillars: list[tuple[float, float]]
    pillar_height: float
    ball_radius: float
    ball_start: tuple[float, float, float]
    ball_velocity: tuple[float, float]
    gap_block_height: float | None = None

    def gap_edges(self) -> tuple[float, float]:
        """x of the inner faces of the outermost pillars (the gap a block fills)."""
        (left_x, left_w), *_, (right_x, right_w) = sorted(self.pillars)
        return left_x + left_w / 2, right_x - right_w / 2


def camera_axes(camera: CameraPose) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Position, right, up and forward unit vectors of MuJoCo's free camera at ``camera``."""
    azimuth, elevation = np.radians(camera.azimuth), np.radians(camera.elevation)
    horizontal = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    vertical = np.array([0.0, 0.0, 1.0])
    forward = np.cos(elevation) * horizontal + np.sin(elevation) * vertical
    up = -np.sin(elevation) * horizontal + np.cos(elevation) * vertical
    position = np.asarray(camera.lookat) - camera.distance * forward
    return position, np.cross(forward, up), up, forward


def project(camera: CameraPose, video: VideoOptions, point, fovy: float = 45.0) -> tuple[int, int]:
    """Pixel (row, column) where the world ``point`` appears in a frame (may lie outside it)."""
    position, right, up, forward = camera_axes(camera)
    offset = np.asarray(point, float) - position
    depth = offset @ forward
    focal = (video.height / 2) / np.tan(np.radians(fovy) / 2)
    column = video.width / 2 + focal * (offset @ right) / depth
    row = video.height / 2 - focal * (offset @ up) / depth
    return int(np.floor(row)), int(np.floor(column))


def build(
    rng: np.random.Generator, video: VideoOptions, camera: CameraPose, layout: Layout
) -> Simulation:
    """Compile the scene and launch the ball rolling (spin matched to its speed, no slip)."""
    builder = SceneBuilder(rng, video, camera)
    pillar_color, block_color, ball_color = rng.choice(base.COLOR_NAMES, size=3, replace=False)
    height = layout.pillar_height
    for index, (x, width) in enumerate(layout.pillars):
        builder.add_primitive(
            f"pillar{index}",
            "box",
            (width / 2, PILLAR_DEPTH / 2, height / 2),
            (x, 0.0, height / 2),
            pillar_color,
            free=False,
        )
    if layout.gap_block_height is not None:
        inner_left, inner_right = layout.gap_edges()
        block_height = layout.gap_block_height
        builder.add_primitive(
            "block",
            "box",
            ((inner_right - inner_left) / 2, PILLAR_DEPTH / 2, block_height / 2),
            ((inner_left + inner_right) / 2, 0.0, block_height / 2),
            block_color,
            free=False,
        )
    radius = layout.ball_radius
    builder.add_primitive("ball", "sphere", (radius,), layout.ball_start, ball_color, density=300.0)
    sim = builder.build()
    vx, vy = layout.ball_velocity
    sim.set_velocity("ball", (vx, vy, 0.0), (-vy / radius, vx / radius, 0.0))
    return sim


def get_state(sim: Simulation) -> np.ndarray:
    """The full integration state (positions, velocities, mocap, warm start) of ``sim``."""
    kind = mujoco.mjtState.mjSTATE_INTEGRATION
    state = np.empty(mujoco.mj_stateSize(sim.model, kind))
    mujoco.mj_getState(sim.model, sim.data, state, kind)
    return state


def set_state(sim: Simulation, state: np.ndarray) -> None:
    """Put ``sim`` into a state saved by ``get_state``."""
    mujoco.mj_setState(sim.model, sim.data, state, mujoco.mjtState.mjSTATE_INTEGRATION)
    mujoco.mj_forward(sim.model, sim.data)


def record_tracking_ball(sim: Simulation) -> tuple[np.ndarray, np.ndarray, list, np.ndarray]:
    """Render the whole video, keeping the state and ball position at every frame."""
    states, positions = [], []

    def keep(sim: Simulation, frame: int) -> None:
        states.append(get_state(sim))
        positions.append(sim.position("ball"))

    frames, masks = sim.record(sim.video.num_frames, keep)
    return frames, masks, states, np.array(positions)


def ball_pixels(masks: np.ndarray, ball_id: int) -> np.ndarray:
    """Visible ball pixels per frame."""
    return (masks == ball_id).sum(axis=(1, 2))


def what_hides_ball(sim: Simulation, masks: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Per frame, the mask id seen at the ball's centre (the ball's own id when it shows, an
    occluder's id when hidden, 0 for floor or -1 when its centre is outside the frame)."""
    video = sim.video
    seen = np.full(len(masks), -1)
    for t, position in enumerate(positions):
        row, column = project(sim.camera, video, position)
        if 0 <= row < video.height and 0 <= column < video.width:
            seen[t] = masks[t, row, column]
    return seen


def column(sim: Simulation, point) -> int:
    """Image column of the world ``point``."""
    return project(sim.camera, sim.video, point)[1]


def probe_layout(rng: np.random.Generator, num_pillars: int, duration: float) -> Layout:
    """Pillars around the centre and a ball rolling behind them, fast enough to be seen before,
    between and after them; with three pillars the third stands in a wider gap."""
    width = float(rng.uniform(0.4, 0.55))
    if num_pillars == 2:
        gap = float(rng.uniform(0.5, 0.9))
        centres = [-(gap + width) / 2, (gap + width) / 2]
        widths = [width, width]
    else:  # the outer pair as in training (a gap from the wide end), a narrow pillar between
        gap = float(rng.uniform(0.8, 0.9))
        middle = float(rng.uniform(0.2, 0.26))
        centres = [-(gap + width) / 2, 0.0, (gap + width) / 2]
        widths = [width, middle, width]
    shift = float(rng.uniform(-0.15, 0.15))
    pillars = [(c + shift, w) for c, w in zip(centres, widths)]
    radius = float(rng.uniform(0.13, 0.17))
    depth = float(rng.uniform(0.3, 0.7))
    direction = float(rng.choice([-1.0, 1.0]))
    span = (centres[-1] + widths[-1] / 2) - (centres[0] - widths[0] / 2)
    lead_in, lead_out = float(rng.uniform(0.25, 0.5)), float(rng.uniform(0.25, 0.5))
    distance = span + lead_in + lead_out + 2 * radius
    speed = distance / (duration * float(rng.uniform(0.85, 0.95)))
    start_x = shift - direction * (span / 2 + lead_in + radius)
    return Layout(
        pillars=pillars,
        pillar_height=float(rng.uniform(0.75, 1.0)),
        ball_radius=radius,
        ball_start=(start_x, depth, radius),
        ball_velocity=(direction * speed, 0.0),
    )


def example_layout(rng: np.random.Generator, duration: float) -> Layout:
    """Two pillars and a ball whose path is unconstrained: in front of or behind the pillars,
    any speed, either direction, slanted, and sometimes dropped from a little height."""
    layout = probe_layout(rng, 2, duration)
    radius = float(rng.uniform(0.08, 0.2))
    angle = float(rng.uniform(-0.35, 0.35))
    speed = float(rng.uniform(0.4, 1.4))
    direction = float(rng.choice([-1.0, 1.0]))
    drop = float(rng.uniform(0.0, 0.5)) if rng.random() < 0.3 else 0.0
    start = (
        float(-direction * rng.uniform(0.3, 1.5)),
        float(rng.uniform(-0.9, 1.0)),
        radius + drop,
    )
    layout.ball_radius = radius
    layout.ball_start = start
    layout.ball_velocity = (direction * speed * np.cos(angle), speed * np.sin(angle))
    layout.pillar_height = float(rng.uniform(0.5, 1.2))
    return layout


def example_camera(rng: np.random.Generator) -> CameraPose:
    """Training clips vary the (static) camera from video to video."""
    return CameraPose(
        lookat=(float(rng.uniform(-0.3, 0.3)), float(rng.uniform(0.2, 0.6)), 0.3),
        distance=float(rng.uniform(3.6, 4.4)),
        azimuth=float(rng.uniform(80.0, 100.0)),
        elevation=float(rng.uniform(-32.0, -23.0)),
    )


def vanish_and_reappear(
    sim: Simulation, layout: Layout, masks: np.ndarray, positions: np.ndarray
) -> tuple[int, int]:
    """The first frame the ball is wholly hidden by the first pillar on its path and the first
    after that it is wholly hidden by the last one; rejects scenes where the ball is not seen
    well before, in every gap between, and after the pillars."""
    ball = sim.mask_id("ball")
    pixels = ball_pixels(masks, ball)
    seen = what_hides_ball(sim, masks, positions)
    order = sorted(range(len(layout.pillars)), key=lambda i: layout.pillars[i][0])
    if layout.ball_velocity[0] < 0:
        order.reverse()
    first, last = (sim.mask_id(f"pillar{i}") for i in (order[0], order[-1]))
    behind_first = np.flatnonzero((seen == first) & (pixels == 0))
    if not len(behind_first):
        raise RejectedSample("the ball is never hidden by the first pillar")
    vanish = int(behind_first[0])
    behind_last = np.flatnonzero((seen == last) & (pixels == 0))
    behind_last = behind_last[behind_last > vanish]
    if not len(behind_last):
        raise RejectedSample("the ball is never hidden by the last pillar")
    reappear = int(behind_last[0])
    well_seen = pixels >= VISIBLE_SHARE * pixels.max()
    if not well_seen[:vanish].any():
        raise RejectedSample("the ball is not seen before the first pillar")
    if not well_seen[reappear:].any():
        raise RejectedSample("the ball is not seen after the last pillar")
    ball_columns = np.array([column(sim, position) for position in positions])
    pillar_columns = [column(sim, (layout.pillars[i][0], 0.0, 0.0)) for i in order]
    for one, other in zip(pillar_columns, pillar_columns[1:]):
        low, high = min(one, other), max(one, other)
        in_gap = (low < ball_columns) & (ball_columns < high) & well_seen
        if not in_gap[vanish:reappear].any():
            raise RejectedSample("the ball is not seen in every gap between the pillars")
    return vanish, reappear


def probe(variant: str, seed: int, video: VideoOptions) -> TensorDict:
    """A consistent/inconsistent pair: ``standard`` (two pillars) or ``three_pillars``. The
    consistent video is rendered whole; the inconsistent one forks from it at the frame the
    ball is hidden by the first pillar, parks the ball, and restores the consistent state
    (ball on course) at the frame it is hidden by the last pillar."""
    specs.check_variant(CONCEPT, variant)
    num_pillars = 3 if variant == "three_pillars" else 2

    def make(rng: np.random.Generator) -> TensorDict:
        layout = probe_layout(rng, num_pillars, video.duration)
        sim = build(rng, video, PROBE_CAMERA, layout)
        frames, masks, states, positions = record_tracking_ball(sim)
        vanish, reappear = vanish_and_reappear(sim, layout, masks, positions)
        twin = sim.fork()
        set_state(twin, states[vanish])
        twin.remove("ball")

        def reappear_on_course(twin: Simulation, frame: int) -> None:
            if frame == reappear:
                restore_ball(twin, sim, states[reappear])

        rest = twin.record(video.num_frames - vanish, reappear_on_course, first_frame=vanish)
        inconsistent = tuple(np.concatenate([a[:vanish], b]) for a, b in zip((frames, masks), rest))
        ball = sim.mask_id("ball")
        return base.probe_record(
            CONCEPT, variant, seed, (frames, masks), inconsistent, PROBE_CAMERA, vanish, [ball]
        )

    return base.draw_until_valid(make, base.rng_for(seed, CONCEPT, variant))


def restore_ball(twin: Simulation, original: Simulation, state: np.ndarray) -> None:
    """Undo ``twin.remove('ball')``: collisions and gravity as in ``original``, and the whole
    state (the ball's position and velocity included) as ``original`` had it at that frame."""
    for geom_name in twin.objects["ball"].geom_names:
        twin.model.geom(geom_name).contype = original.model.geom(geom_name).contype
        twin.model.geom(geom_name).conaffinity = original.model.geom(geom_name).conaffinity
    body = twin.model.body("ball").id
    twin.model.body_gravcomp[body] = original.model.body_gravcomp[body]
    set_state(twin, state)


def clip(kind: str, seed: int, video: VideoOptions) -> TensorDict:
    """A training clip: an ``example`` with an unconstrained ball path, or the ``gap_block``
    control where a block fills the gap so the ball shows only before and after the pillars."""
    specs.check_kind(CONCEPT, kind)

    def make(rng: np.random.Generator) -> TensorDict:
        if kind == "example":
            camera = example_camera(rng)
            layout = example_layout(rng, video.duration)
        else:
            camera = PROBE_CAMERA
            layout = probe_layout(rng, 2, video.duration)
            layout.gap_block_height = layout.pillar_height * float(rng.uniform(0.75, 1.0))
        sim = build(rng, video, camera, layout)
        frames, masks, _, positions = record_tracking_ball(sim)
        pixels = ball_pixels(masks, sim.mask_id("ball"))
        if (pixels > 0).sum() < video.num_frames / 3:
            raise RejectedSample("the ball is seen in less than a third of the frames")
        if kind == "gap_block":
            seen = what_hides_ball(sim, masks, positions)
            if not (seen == sim.mask_id("block")).any():
                raise RejectedSample("the block never hides the ball")
            low, high = sorted(column(sim, (x, 0.0, 0.0)) for x in layout.gap_edges())
            for t, position in enumerate(positions):
                if low < column(sim, position) < high and pixels[t]:
                    raise RejectedSample("the ball shows above the gap block")
        return base.clip_record(CONCEPT, kind, seed, frames, masks, camera)

    return base.draw_until_valid(make, base.rng_for(seed, CONCEPT, kind))
