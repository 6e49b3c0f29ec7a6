"""Solidity (paper §3, after Hespos & Baillargeon 2001): a rectangular block is dropped into an
open container. In probes the camera sees inside the top of the container but not its bottom.
An unseen hand lowers the block (in probes from above the view, so that the first frame shows
no block) and holds it still for a moment before it lets go, in examples for anything from no
time to over a second, in probes long enough that a model sees it for several frames before
the hidden change. ``standard`` and ``counterbalanced`` are one quadruplet per seed: one
container, camera, footprint and timing, with a tall block (A: it comes to rest on the floor
protruding above the rim) or a short one (B: it sinks out of sight), hung with their tops level
so that they fall alike. At the manipulation frame both have fallen
FALL_TIME, their bottoms hidden by the front wall and only their level tops showing, so they
render alike; the standard inconsistent video (A, then B) shows the tall block sink out of
sight as if through the container and the floor, the counterbalanced one (B, then A) the short
block stop protruding as if on something hidden. After the change each inconsistent video's
frames and masks are exactly the other variant's consistent one's; its block keeps its own size
in the object states, its top where the other block's top is (``keep_the_block``), so the states
show the tall block sink through the floor or the short one stop above it, as the frames do,
and never a block that changes height. Examples vary heights and perspective freely;
controls show the container alone, or the block falling behind it and ending hidden by it."""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, cast

import numpy as np
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes import recording
from voe_lightning.scenes.appearance import distinct_colors
from voe_lightning.scenes.builder import SceneBuilder, yaw_quat
from voe_lightning.scenes.camera import CameraPose, CameraRange, VideoOptions, height_above_view
from voe_lightning.scenes.container import container_geoms, hides, outer_gap
from voe_lightning.scenes.sampling import RejectedSample, draw_until_valid, rng_for
from voe_lightning.scenes.simulation import Simulation, visible_ids

CONCEPT = "solidity"
VARIANTS = ("standard", "counterbalanced")
#: Pixels of the block that the inconsistent video may show beyond the consistent one (edges).
PENETRATION_TOLERANCE = 2

#: The one camera distribution of the concept: examples and every control draw from it.
CAMERA = CameraRange(
    lookat_x=(0.0, 0.0),
    lookat_y=(0.0, 0.0),
    lookat_z=(0.2, 0.75),
    distance=(2.4, 3.6),
    azimuth=(50.0, 130.0),
    elevation=(-55.0, -12.0),
)
#: Probes' controlled perspective (paper: the camera sees inside the top, not the bottom): a
#: frontal sub-range of CAMERA, further held to ``sees_top_not_bottom`` for each container.
PROBE_CAMERA = CAMERA.narrow(
    lookat_z=(0.4, 0.75), distance=(2.4, 3.0), azimuth=(85.0, 95.0), elevation=(-40.0, -12.0)
)
#: Block height as a multiple of the container's inner depth: examples range from fully hidden
#: to protruding. Probes' heights follow from PROTRUSION and lie inside this range.
EXAMPLE_HEIGHTS = (0.2, 1.5)
#: Height of the block's bottom above the rim when it is released (probes: inside this range).
EXAMPLE_DROP = (0.05, 0.6)
#: How long the block hangs still before it is let go (s; examples: rounded down to whole
#: frames, see ``release_frame``). Probes let it go 0.8 to 1.2 s in, 4 to 6 frames at 15 frames
#: over 3 s, after LOWERING: dropped at once, a block reaches the rim within one or two frames.
EXAMPLE_HOLD = (0.0, 1.2)
PROBE_HOLD = (0.8, 1.2)
#: The unseen hand first lowers the block from ``lift`` above where it hangs (examples: in
#: EXAMPLE_LIFT), at a steady speed over LOWERING s (``hand_controller``; an example's block let go sooner falls on from that speed).
#: Probes lower it from wholly above the view, LIFT_MARGIN or more above the image's top edge,
#: so that the first frame of both videos of a quadruplet shows the container and the floor
#: with no block before them: every place the block ever covers has been seen uncovered, and a
#: memory of the frames before the change finds nothing new where B's block sinks away that A's
#: past never showed (docs/stimuli.md, "pixel novelty").
LOWERING = 0.4
EXAMPLE_LIFT = (0.0, 1.2)
LIFT_MARGIN = 0.05
#: Of the back wall's inner face, the probe camera hides at least/at most this fraction.
HIDDEN_BACK_WALL = (0.3, 0.9)
#: How far a probe's tall block, resting on the floor, rises above the sight line over the
#: front rim (at its highest over the footprint).
PROTRUSION = (0.04, 0.2)
#: How far below the sight line anything hidden stays (the short block's bottom at the change,
#: its top at rest on the floor).
MARGIN = 0.03
#: Probes: how long the blocks have fallen at the manipulation frame (s), and how far above the
#: floor the tall one is then (the short one goes on falling).
FALL_TIME = 0.4
CLEARANCE = (0.01, 0.05)
GRAVITY = 9.81  # MuJoCo's default, which the scenes keep
#: Outer height of the container.
CONTAINER_HEIGHT = (0.55, 0.8)
#: A container's sizes, a block's or a scene draw's parameters, by name; a floor point (x, y).
Box = dict[str, float]
Params = dict[str, Any]
Point = Sequence[float] | np.ndarray


def _draw_container(rng: np.random.Generator) -> Box:
    """An open box: interior half width/depth, wall half thickness and outer height."""
    return {
        "inner_x": float(rng.uniform(0.35, 0.6)),
        "inner_y": float(rng.uniform(0.25, 0.4)),
        "wall": float(rng.uniform(0.025, 0.04)),
        "height": float(rng.uniform(*CONTAINER_HEIGHT)),
    }


def _depth(box: Box) -> float:
    """Inner depth: from the top of the container's bottom to its rim."""
    return box["height"] - 2 * box["wall"]


def _add_container(builder: SceneBuilder, box: Box, color: str) -> None:
    """The container as one fixed object of five box geoms (bottom and four walls)."""
    geoms = container_geoms(box["inner_x"], box["inner_y"], box["height"], 2 * box["wall"])
    builder.add("container", geoms, (0.0, 0.0, 0.0), color, free=False)


def camera_position(camera: CameraPose) -> np.ndarray:
    """Where MuJoCo's free camera sits for ``camera`` (its eye, in world coordinates)."""
    azimuth, elevation = np.deg2rad(camera.azimuth), np.deg2rad(camera.elevation)
    horizontal = np.cos(elevation)
    forward = np.array(
        [horizontal * np.cos(azimuth), horizontal * np.sin(azimuth), np.sin(elevation)]
    )
    return np.asarray(camera.lookat, float) - camera.distance * forward


def _hidden_height(eye: np.ndarray, box: Box, x: float, y: float) -> float:
    """The highest point above (x, y) inside the container that the front wall hides from
    ``eye``: the sight line over the front rim (y = -inner_y, z = height) meets it there."""
    reach = (-box["inner_y"] - eye[1]) / (y - eye[1])  # fraction of the way at the front face
    return float(eye[2] + (box["height"] - eye[2]) / reach)


def sees_top_not_bottom(camera: CameraPose, box: Box) -> bool:
    """The probe perspective: from in front of and above the container, the sight line over
    the front rim meets the back wall's inner face between HIDDEN_BACK_WALL of its depth."""
    eye = camera_position(camera)
    if eye[1] >= -(box["inner_y"] + 2 * box["wall"]) or eye[2] <= box["height"]:
        return False
    floor, depth = 2 * box["wall"], _depth(box)
    low, high = (box["height"] - f * depth for f in reversed(HIDDEN_BACK_WALL))
    heights = [
        _hidden_height(eye, box, x, box["inner_y"]) for x in (-box["inner_x"], 0.0, box["inner_x"])
    ]
    return floor < low <= min(heights) and max(heights) <= high


def _footprint(block: Params, xy: Point) -> np.ndarray:
    """The four corners (x, y) of the block's yawed footprint centred at ``xy``, [4, 2]."""
    half_x, half_y, _ = block["half"]
    cos, sin = np.cos(block["yaw"]), np.sin(block["yaw"])
    local = np.array([[sx * half_x, sy * half_y] for sx in (-1, 1) for sy in (-1, 1)])
    return cast(np.ndarray, np.asarray(xy, float) + local @ np.array([[cos, sin], [-sin, cos]]))


def _draw_block(rng: np.random.Generator, box: Box, heights: tuple[float, float]) -> Params:
    """A block that fits inside the container upright, its height a random multiple (in
    ``heights``) of the container's inner depth, with a small random yaw."""
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
    half_z = float(rng.uniform(*heights) * _depth(box) / 2)
    return {"half": (half_x, half_y, half_z), "yaw": yaw, "offset": offset}


def draw_example(rng: np.random.Generator) -> Params:
    """The parameters of a training clip: container, block, camera, drop height, how far the
    block is lowered to it and how long it is held before it drops."""
    box = _draw_container(rng)
    return {
        "box": box,
        "block": _draw_block(rng, box, EXAMPLE_HEIGHTS),
        "camera": CAMERA.sample(rng),
        "drop": float(rng.uniform(*EXAMPLE_DROP)),
        "lift": float(rng.uniform(*EXAMPLE_LIFT)),
        "hold": float(rng.uniform(*EXAMPLE_HOLD)),
    }


def release_frame(hold: float, video: VideoOptions) -> int:
    """The last frame showing an example's block held, ``hold`` seconds in: it is let go right
    after that frame (``hand_controller`` at its first physics step), so that it has fallen one
    frame interval's drop at the next one (from rest, if LOWERING is over by then)."""
    return int(hold // (video.steps_per_frame * video.timestep))


def _fall_steps(video: VideoOptions) -> int:
    """Physics steps the probe's block falls before the manipulation frame (FALL_TIME)."""
    return round(FALL_TIME / video.timestep)


def fall_distance(video: VideoOptions) -> float:
    """How far the probe's block falls from rest in ``_fall_steps``: MuJoCo's semi-implicit
    Euler step adds g·dt to the speed, then moves by the new speed, so n steps fall
    g·dt²·n(n+1)/2 (2 cm more than g·t²/2 at 0.4 s in 1 cm steps)."""
    steps = _fall_steps(video)
    return GRAVITY * video.timestep**2 * steps * (steps + 1) / 2


def manipulation_frames(video: VideoOptions) -> list[int]:
    """The frames a probe's hidden change may come at: the block let go PROBE_HOLD s in (a
    physics step, not necessarily a frame) has fallen FALL_TIME s there, and two frames or more
    follow."""
    release = [m * video.steps_per_frame - _fall_steps(video) for m in range(video.num_frames - 2)]
    return [
        m
        for m, step in enumerate(release)
        if m >= 1 and PROBE_HOLD[0] - 1e-9 <= step * video.timestep <= PROBE_HOLD[1] + 1e-9
    ]


def hand_controller(sim: Simulation, lift: float, release: int) -> Callable[[Simulation], None]:
    """A controller (run before every physics step) for the unseen hand that holds the block,
    its weight compensated (``_add_block``): it lowers it ``lift`` at a steady speed over
    LOWERING s, holds it still and lets it go at physics step ``release``, at whatever speed it
    has then. Examples let go right after a frame, probes between frames if need be (they time
    the fall, not the frames)."""
    block, timestep = sim.model.body("block").id, sim.model.opt.timestep
    lowering = round(LOWERING / timestep)
    speed = lift / (lowering * timestep)

    def controller(sim: Simulation) -> None:
        step = round(sim.data.time / timestep)
        if step >= release:
            sim.model.body_gravcomp[block] = 0.0
        else:
            sim.set_velocity("block", (0.0, 0.0, -speed if step < lowering else 0.0))

    return controller


def check_video(video: VideoOptions) -> None:
    """Refuse videos too short for the probes (no frame where the block, let go PROBE_HOLD s
    in, has fallen FALL_TIME s with two frames left), naming the num_frames that would do;
    ``generate`` calls it before rendering anything."""
    if manipulation_frames(video):
        return
    frame_time = video.steps_per_frame * video.timestep
    enough = next(
        n
        for n in range(video.num_frames + 1, 10 * video.num_frames + 100)
        if manipulation_frames(
            replace(video, num_frames=n, timestep=min(video.timestep, video.duration / n))
        )
    )
    raise ValueError(
        f"{CONCEPT} probes need a frame {PROBE_HOLD[0] + FALL_TIME:g} to "
        f"{PROBE_HOLD[1] + FALL_TIME:g} s in with two more after it (the block hangs "
        f"{PROBE_HOLD[0]:g} to {PROBE_HOLD[1]:g} s, then falls {FALL_TIME:g} s before the hidden "
        f"change), got {video.num_frames} frames {frame_time:.2f} s apart over "
        f"{video.duration:g} s; use num_frames >= {enough}"
    )


def draw_quadruplet(rng: np.random.Generator, video: VideoOptions = VideoOptions()) -> Params:
    """The parameters of a probe quadruplet, each inside the examples' range: a container seen
    from the controlled perspective, a block footprint, two heights for it and when it is let
    go. ``tall`` rests on the floor protruding PROTRUSION above the sight line over the front
    rim; ``short`` sinks out of sight. Both are lowered ``lift`` from above the view, hang with
    their tops level and fall together, so that at ``manipulation_frame`` (fallen FALL_TIME,
    the tall block CLEARANCE above the floor) both bottoms are hidden and the two look alike;
    ``drops`` are their bottoms' heights above the rim when let go."""
    check_video(video)
    frames, fall = manipulation_frames(video), fall_distance(video)
    for _ in range(1000):
        box, camera = _draw_container(rng), PROBE_CAMERA.sample(rng)
        if not sees_top_not_bottom(camera, box):
            continue
        block = _draw_block(rng, box, EXAMPLE_HEIGHTS)
        eye = camera_position(camera)
        hidden = [_hidden_height(eye, box, x, y) for x, y in _footprint(block, block["offset"])]
        floor, depth = 2 * box["wall"], _depth(box)
        protrusion, clearance = rng.uniform(*PROTRUSION), rng.uniform(*CLEARANCE)
        manipulation_frame = int(rng.choice(frames))
        top = max(hidden) + protrusion + clearance  # both blocks' top at the change
        # The short block's bottom is hidden at the change, its top once it rests.
        low, high = top - min(hidden) + MARGIN, min(hidden) - MARGIN - floor
        if not low < high:
            continue
        heights = {"tall": top - clearance - floor, "short": float(rng.uniform(low, high))}
        drops = {name: top + fall - height - box["height"] for name, height in heights.items()}
        lift = _lift_out_of_view(camera, block, box["height"] + drops["tall"])
        if (
            all(
                EXAMPLE_HEIGHTS[0] <= height / depth <= EXAMPLE_HEIGHTS[1]
                for height in heights.values()
            )
            and all(EXAMPLE_DROP[0] <= drop <= EXAMPLE_DROP[1] for drop in drops.values())
            and EXAMPLE_LIFT[0] <= lift <= EXAMPLE_LIFT[1]
        ):
            release = manipulation_frame * video.steps_per_frame - _fall_steps(video)
            return {
                "box": box,
                "block": block,
                "camera": camera,
                "heights": heights,
                "drops": drops,
                "lift": lift,
                "hold": release * video.timestep,
                "manipulation_frame": manipulation_frame,
            }
    raise RuntimeError(f"no {CONCEPT} probe quadruplet parameters in 1000 draws")


def _lift_out_of_view(camera: CameraPose, block: Params, bottom: float) -> float:
    """How far to lift ``block``, its bottom hanging at ``bottom``, for all of it to lie
    LIFT_MARGIN or more above the top edge of ``camera``'s view: its bottom corners are the
    lowest points of it and the view's top face slopes less than vertical."""
    corners = _footprint(block, block["offset"])
    return max(height_above_view(camera, x, y) for x, y in corners) - bottom + LIFT_MARGIN


def draw_probe(
    variant: str, rng: np.random.Generator, video: VideoOptions = VideoOptions()
) -> Params:
    """The parameters of ``variant``'s consistent scene in a quadruplet (``draw_quadruplet``):
    ``standard`` the tall block, ``counterbalanced`` the short one; ``block`` carries its
    height, ``drop`` its start above the rim."""
    specs.check_variant(CONCEPT, variant)
    params = draw_quadruplet(rng, video)
    return _scene(params, "tall" if variant == "standard" else "short")


def _scene(params: Params, size: str) -> Params:
    """One of a quadruplet's two scenes: its block ``size`` (tall or short) in ``params``."""
    half = params["block"]["half"]
    block = {**params["block"], "half": (half[0], half[1], params["heights"][size] / 2)}
    return {**params, "block": block, "drop": float(params["drops"][size])}


def _add_block(builder: SceneBuilder, block: Params, xy: Point, bottom: float, color: str) -> None:
    """The block, its weight compensated (it hangs still) until ``hand_controller`` lets
    it go."""
    builder.add_primitive(
        "block",
        "box",
        block["half"],
        (xy[0], xy[1], bottom + block["half"][2]),
        color,
        quat=yaw_quat(block["yaw"]),
    )
    builder.spec.body("block").gravcomp = 1.0


def probe(variant: str, seed: int, video: VideoOptions) -> TensorDict:
    """A probe pair of ``variant``, one half of the seed's quadruplet (``quadruplet``):
    ``standard`` (a tall block rests protruding, or after the change sinks out of view as if
    through the floor) or ``counterbalanced`` (a short block sinks out of view, or after the
    change stops protruding above the rim as if on something hidden)."""
    specs.check_variant(CONCEPT, variant)
    return recording.quadruplet_record(CONCEPT, variant, seed, quadruplet(seed, video))


@functools.lru_cache(maxsize=4)
def quadruplet(seed: int, video: VideoOptions) -> recording.Quadruplet:
    """One scene draw's quadruplet ((A, AB), (B, BA)) (``draw_quadruplet``): A the tall block
    resting protruding, B the short one sinking out of sight, spliced at the manipulation
    frame, where only their level tops show; with the camera, that frame and the block's mask
    id. Cached, as both variants of a seed read it (callers copy what they keep)."""

    def make(rng: np.random.Generator) -> recording.Quadruplet:
        params = draw_quadruplet(rng, video)
        box, camera, frame = params["box"], params["camera"], params["manipulation_frame"]
        container_color, block_color = distinct_colors(rng, 2)
        scene_seed = int(rng.integers(2**63))  # one draw of the stage for both scenes
        videos, sims = [], []
        for size in ("tall", "short"):
            scene = _scene(params, size)
            builder = SceneBuilder(np.random.default_rng(scene_seed), video, camera)
            _add_container(builder, box, container_color)
            block = scene["block"]
            bottom = box["height"] + scene["drop"] + params["lift"]
            _add_block(builder, block, block["offset"], bottom, block_color)
            sim = builder.build()
            release = round(params["hold"] / video.timestep)
            sim.controller = hand_controller(sim, params["lift"], release)
            videos.append(sim.record(video.num_frames))
            sims.append(sim)
        block_id = sim.mask_id("block")
        (_, tall, _), (_, short, _) = videos
        if block_id in visible_ids(tall[0]) | visible_ids(short[0]):
            raise RejectedSample("the block is seen in the first frame, before it is lowered")
        extra = (short[frame:] == block_id) & (tall[frame:] != block_id)
        if extra.sum(axis=(1, 2)).max() > PENETRATION_TOLERANCE:
            raise RejectedSample("the short block shows where the tall one does not")
        if (tall[-1] == block_id).sum() < 6:
            raise RejectedSample("the protruding block is hidden: the pair would not differ")
        if block_id in visible_ids(short[-1]):
            raise RejectedSample("the block that should be out of view is seen at the end")
        pairs = recording.quadruplet(videos[0], videos[1], frame)
        for (own, spliced), puppet in zip(pairs, sims):
            keep_the_block(own, spliced, block_id, frame)
            if _shown_apart(puppet, spliced, block_id, frame) > PENETRATION_TOLERANCE:
                raise RejectedSample("the spliced block's states would not render as its frames")
        return pairs, camera.as_array(), frame, block_id

    return draw_until_valid(make, rng_for(seed, CONCEPT, "quadruplet"))


def keep_the_block(own: recording.Video, spliced: recording.Video, block_id: int, m: int) -> None:
    """Give the spliced video's block, after the change at ``m``, its own size (the one ``own``,
    its consistent video, shows) with its top where the other block's top is: the hidden change
    is the block's path through (or stop above) the floor, not a swap of blocks, which a
    learner reading states would see as a block changing height (issue 70). In place."""
    objects, half = spliced[2], own[2]["size"][m, block_id]
    objects["position"][m + 1 :, block_id, 2] += objects["size"][m + 1 :, block_id, 2] - half[2]
    objects["size"][m + 1 :, block_id] = half


def _shown_apart(sim: Simulation, spliced: recording.Video, block_id: int, m: int) -> int:
    """The most pixels, over the frames after ``m``, where ``sim``'s block placed as the spliced
    video's states say shows and the spliced video's mask does not, or the reverse: the states
    must render as the frames (only the level tops show)."""
    _, masks, objects = spliced
    apart = 0
    for t in range(m + 1, len(masks)):
        sim.move("block", objects["position"][t, block_id], objects["orientation"][t, block_id])
        _, mask, _ = sim.render()
        apart = max(apart, int(((mask == block_id) != (masks[t] == block_id)).sum()))
    return apart


def _behind_container(
    rng: np.random.Generator, box: Box, block: Params, camera: CameraPose
) -> np.ndarray:
    """A floor position for ``block`` behind the container as the camera sees it: along the
    line of sight, just past where the block's footprint clears the container."""
    view = np.deg2rad(camera.azimuth)
    along = np.array([np.cos(view), np.sin(view)])
    across = np.array([-along[1], along[0]])
    start = along * box["inner_y"] + across * rng.uniform(-0.5, 0.5) * box["inner_x"]
    radius = float(np.hypot(*block["half"][:2]))
    behind = 0.0
    while outer_gap(_outer(box), start + behind * along) <= radius:
        behind += 0.02
    return start + (behind + rng.uniform(0.03, 0.15)) * along


def _outer(box: Box) -> tuple[float, float]:
    """The container's outer half-sizes (x, y)."""
    return box["inner_x"] + 2 * box["wall"], box["inner_y"] + 2 * box["wall"]


def clip(kind: str, seed: int, video: VideoOptions) -> TensorDict:
    """A training clip: ``example`` (a block of any height drops into the container, seen from
    any perspective), ``no_object`` (the container alone) or ``object_behind_container`` (the
    block falls behind the container and ends hidden by it)."""

    def draw_scene(rng: np.random.Generator) -> tuple[CameraPose, recording.Video]:
        params = draw_example(rng)
        box, block, camera = params["box"], params["block"], params["camera"]
        container_color, block_color = distinct_colors(rng, 2)
        builder = SceneBuilder(rng, video, camera)
        _add_container(builder, box, container_color)
        drop = box["height"] + params["drop"] + params["lift"]
        if kind == "example":
            _add_block(builder, block, block["offset"], drop, block_color)
        elif kind == "object_behind_container":
            # Redraw the block (camera kept, so the control's cameras are the examples') until,
            # resting behind the container, it is hidden by it.
            eye = camera_position(camera)
            for _ in range(200):
                xy = _behind_container(rng, box, block, camera)
                corners = _footprint(block, xy)
                points = np.array(
                    [[x, y, z] for x, y in corners for z in (0.0, 2 * block["half"][2])]
                )
                if hides(eye, _outer(box), box["height"], points, margin=0.03):
                    break
                block = _draw_block(rng, box, EXAMPLE_HEIGHTS)
            else:
                raise RejectedSample("no block hides behind the container from this camera")
            _add_block(builder, block, xy, drop, block_color)
        sim = builder.build()
        if kind != "no_object":
            released = release_frame(params["hold"], video)
            sim.controller = hand_controller(sim, params["lift"], released * video.steps_per_frame)
        frames, masks, objects = sim.record(video.num_frames)
        if kind != "no_object" and sim.mask_id("block") not in set().union(
            *map(visible_ids, masks[: released + 1])
        ):
            raise RejectedSample("the block is not seen before it falls")
        if kind == "object_behind_container" and sim.mask_id("block") in visible_ids(masks[-1]):
            raise RejectedSample("the block behind the container is still seen at the end")
        return camera, (frames, masks, objects)

    return recording.draw_clip(CONCEPT, kind, seed, draw_scene)
