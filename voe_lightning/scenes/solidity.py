"""Solidity (paper §3, after Hespos & Baillargeon 2001): a rectangular block is dropped into an
open container. In probes the camera sees inside the top of the container but not its bottom.
The block hangs still for a moment before it is let go (as if by an unseen hand), in examples
for anything from no time to over a second, in probes long enough that a model sees it for
several frames before the hidden change. ``standard``: a tall block comes to rest protruding
(consistent) or falls through the container and the floor, its collisions switched off once
inside, the penetration hidden by the front face (inconsistent). ``counterbalanced`` mirrors
it: a short block sinks out of sight (consistent) or lands on a hidden support high in the
container and stays protruding (inconsistent). Examples vary heights and perspective freely;
controls show the container alone, or the block falling behind it and ending hidden by it."""

from __future__ import annotations

from typing import Callable

import numpy as np
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes.appearance import distinct_colors
from voe_lightning.scenes.builder import Geom, SceneBuilder, yaw_quat
from voe_lightning.scenes.camera import CameraPose, CameraRange, VideoOptions
from voe_lightning.scenes.recording import record_pair_when
from voe_lightning.scenes.sampling import RejectedSample, draw_until_valid, rng_for
from voe_lightning.scenes.simulation import Simulation, visible_ids

CONCEPT = "solidity"
VARIANTS = ("standard", "counterbalanced")
CLIP_KINDS = ("example", "no_object", "object_behind_container")
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
#: to protruding; standard probes protrude, counterbalanced probes hide when resting.
EXAMPLE_HEIGHTS = (0.2, 1.5)
PROBE_HEIGHTS = {"standard": (1.0, 1.4), "counterbalanced": (0.2, 0.7)}
#: Height of the block's bottom above the rim when it is released.
EXAMPLE_DROP = (0.05, 0.6)
PROBE_DROP = (0.05, 0.35)
#: How long the block hangs still before it is let go (s, rounded down to whole frames, see
#: ``release_frame``). Probes hold it for 4-6 frames at 15 frames over 3 s: dropped at once,
#: a block reaches the rim (the earliest hidden change) within one or two frames.
EXAMPLE_HOLD = (0.0, 1.2)
PROBE_HOLD = (0.6, 1.2)
#: Of the back wall's inner face, the probe camera hides at least/at most this fraction.
HIDDEN_BACK_WALL = (0.3, 0.9)
#: How far a probe's resting block must rise above the sight line over the front rim to show,
#: and how far below it anything hidden must stay.
PROTRUSION = 0.04
MARGIN = 0.03
#: Counterbalanced probes: how far above the hidden support the block is at the first frame.
CLEARANCE = (0.01, 0.05)
GRAVITY = 9.81  # MuJoCo's default, which the scenes keep
#: Outer height of the container.
CONTAINER_HEIGHT = (0.55, 0.8)


def _draw_container(rng: np.random.Generator) -> dict:
    """An open box: interior half width/depth, wall half thickness and outer height."""
    return {
        "inner_x": float(rng.uniform(0.35, 0.6)),
        "inner_y": float(rng.uniform(0.25, 0.4)),
        "wall": float(rng.uniform(0.025, 0.04)),
        "height": float(rng.uniform(*CONTAINER_HEIGHT)),
    }


def _depth(box: dict) -> float:
    """Inner depth: from the top of the container's bottom to its rim."""
    return box["height"] - 2 * box["wall"]


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


def camera_position(camera: CameraPose) -> np.ndarray:
    """Where MuJoCo's free camera sits for ``camera`` (its eye, in world coordinates)."""
    azimuth, elevation = np.deg2rad(camera.azimuth), np.deg2rad(camera.elevation)
    horizontal = np.cos(elevation)
    forward = np.array(
        [horizontal * np.cos(azimuth), horizontal * np.sin(azimuth), np.sin(elevation)]
    )
    return np.asarray(camera.lookat, float) - camera.distance * forward


def _hidden_height(eye: np.ndarray, box: dict, x: float, y: float) -> float:
    """The highest point above (x, y) inside the container that the front wall hides from
    ``eye``: the sight line over the front rim (y = -inner_y, z = height) meets it there."""
    reach = (-box["inner_y"] - eye[1]) / (y - eye[1])  # fraction of the way at the front face
    return float(eye[2] + (box["height"] - eye[2]) / reach)


def sees_top_not_bottom(camera: CameraPose, box: dict) -> bool:
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


def _footprint(block: dict, xy) -> np.ndarray:
    """The four corners (x, y) of the block's yawed footprint centred at ``xy``, [4, 2]."""
    half_x, half_y, _ = block["half"]
    cos, sin = np.cos(block["yaw"]), np.sin(block["yaw"])
    local = np.array([[sx * half_x, sy * half_y] for sx in (-1, 1) for sy in (-1, 1)])
    return np.asarray(xy, float) + local @ np.array([[cos, sin], [-sin, cos]])


def _draw_block(rng: np.random.Generator, box: dict, heights: tuple[float, float]) -> dict:
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


def draw_example(rng: np.random.Generator) -> dict:
    """The parameters of a training clip: container, block, camera, drop height and how long
    the block is held before it drops."""
    box = _draw_container(rng)
    return {
        "box": box,
        "block": _draw_block(rng, box, EXAMPLE_HEIGHTS),
        "camera": CAMERA.sample(rng),
        "drop": float(rng.uniform(*EXAMPLE_DROP)),
        "hold": float(rng.uniform(*EXAMPLE_HOLD)),
    }


def release_frame(hold: float, video: VideoOptions) -> int:
    """The last frame showing the block held still, ``hold`` seconds in: it is let go right
    after that frame, so that it has fallen one frame interval's drop at the next one."""
    return int(hold // (video.steps_per_frame * video.timestep))


def release_script(sim: Simulation, frame: int) -> Callable[[Simulation, int], None]:
    """A per-frame script that lets the block go once ``frame`` is rendered: until then its
    weight is compensated (``_add_block``), so it hangs still."""
    block = sim.model.body("block").id

    def script(sim: Simulation, rendering: int) -> None:
        if rendering == frame:
            sim.model.body_gravcomp[block] = 0.0

    return script


def check_video(video: VideoOptions) -> None:
    """Refuse frames too far apart for the counterbalanced probes (the block must still be
    above the hidden support a frame after it is let go), naming the num_frames that would do;
    ``generate`` calls it before rendering anything."""
    frame_time = video.steps_per_frame * video.timestep
    longest_fall = CONTAINER_HEIGHT[1] + PROBE_DROP[1]
    if GRAVITY * frame_time**2 / 2 > longest_fall:
        longest = float(np.sqrt(2 * longest_fall / GRAVITY))
        raise ValueError(
            f"{CONCEPT} counterbalanced probes need frames at most {longest:.2f} s apart (the block "
            "must still be above the hidden support a frame after it is let go), got "
            f"{frame_time:.2f} s "
            f"({video.num_frames} frames over {video.duration:g} s); use num_frames >= "
            f"{int(np.ceil(video.duration / longest))}"
        )


def draw_probe(
    variant: str, rng: np.random.Generator, video: VideoOptions = VideoOptions()
) -> dict:
    """The parameters of a probe pair, each inside the examples' range: a container seen from
    the controlled perspective; a block that, resting on the container's floor, protrudes
    into view (standard) or hides below the sight line over the front rim (counterbalanced),
    which then also gets the height of the hidden support (``support``: its top)."""
    if variant not in VARIANTS:
        raise ValueError(
            f"unknown {CONCEPT} probe variant {variant!r}; valid: {', '.join(VARIANTS)}"
        )
    if variant == "counterbalanced":
        check_video(video)
    for _ in range(1000):
        box, camera = _draw_container(rng), PROBE_CAMERA.sample(rng)
        if not sees_top_not_bottom(camera, box):
            continue
        block = _draw_block(rng, box, PROBE_HEIGHTS[variant])
        eye = camera_position(camera)
        corners = _footprint(block, block["offset"])
        hidden = [_hidden_height(eye, box, x, y) for x, y in corners]
        top = 2 * box["wall"] + 2 * block["half"][2]
        params = {"box": box, "block": block, "camera": camera}
        params["hold"] = float(rng.uniform(*PROBE_HOLD))
        if variant == "standard" and top > max(hidden) + PROTRUSION:
            return {**params, "drop": float(rng.uniform(*PROBE_DROP))}
        if variant == "counterbalanced" and top < min(hidden) - MARGIN:
            # The support hides just below the sight line; on it the block protrudes. The drop
            # is timed so that a frame after it is let go the block is just above the support:
            # landing on it moves the block little, as the standard's landing on the floor does.
            support = min(hidden) - MARGIN
            fall = GRAVITY * (video.steps_per_frame * video.timestep) ** 2 / 2
            drop = support + rng.uniform(*CLEARANCE) + fall - box["height"]
            if support + 2 * block["half"][2] > max(hidden) + PROTRUSION and (
                PROBE_DROP[0] <= drop <= PROBE_DROP[1]
            ):
                return {**params, "support": support, "drop": float(drop)}
    raise RuntimeError(f"no {CONCEPT} {variant} probe parameters in 1000 draws")


def _add_block(builder: SceneBuilder, block: dict, xy, bottom: float, color: str) -> None:
    """The block, its weight compensated (it hangs still) until ``release_script`` lets it go."""
    builder.add_primitive(
        "block",
        "box",
        block["half"],
        (xy[0], xy[1], bottom + block["half"][2]),
        color,
        quat=yaw_quat(block["yaw"]),
    )
    builder.spec.body("block").gravcomp = 1.0


def _add_support(builder: SceneBuilder, box: dict, block: dict, top: float, color: str) -> None:
    """The hidden support of the counterbalanced probe: a pedestal under the block's footprint
    from the container's floor up to ``top`` (solid, so a fast block cannot tunnel through it).
    A mocap body, so that it can wait out of the scene (``Simulation.remove``) until the
    manipulation puts it back."""
    half_x, half_y, _ = block["half"]
    x, y = block["offset"]
    floor = 2 * box["wall"]
    builder.add(
        "support",
        [Geom("box", (half_x, half_y, (top - floor) / 2))],
        (x, y, (top + floor) / 2),
        color,
        quat=yaw_quat(block["yaw"]),
        free=False,
        mocap=True,
    )


def _block_bottom(sim: Simulation) -> float:
    return float(sim.position("block")[2] - sim.model.geom("block_0").size[2])


def _fall_through(twin: Simulation) -> None:
    """The magic: the block stops colliding, so it falls through the container and the floor."""
    for geom_name in twin.objects["block"].geom_names:
        twin.model.geom(geom_name).contype = 0
        twin.model.geom(geom_name).conaffinity = 0


def _make_solid(twin: Simulation) -> None:
    """The magic: the hidden support appears in the container, so the block lands on it."""
    twin.restore("support")


def probe(variant: str, seed: int, video: VideoOptions) -> TensorDict:
    """A probe pair: ``standard`` (a tall block rests protruding, or falls through the container
    out of view) or ``counterbalanced`` (a short block sinks out of view, or stays protruding
    on a hidden support; the support, never visible, is the manipulated object)."""
    if variant not in VARIANTS:
        raise ValueError(
            f"unknown {CONCEPT} probe variant {variant!r}; valid: {', '.join(VARIANTS)}"
        )
    rng = rng_for(seed, CONCEPT, variant)

    def make(rng: np.random.Generator) -> TensorDict:
        params = draw_probe(variant, rng, video)
        box, block, camera = params["box"], params["block"], params["camera"]
        container_color, block_color = distinct_colors(rng, 2)
        builder = SceneBuilder(rng, video, camera)
        _add_container(builder, box, container_color)
        _add_block(builder, block, block["offset"], box["height"] + params["drop"], block_color)
        if variant == "counterbalanced":
            _add_support(builder, box, block, params["support"], container_color)
        sim = builder.build()
        if variant == "counterbalanced":
            sim.remove("support")
        block_id = sim.mask_id("block")
        rim = box["height"] - 0.02
        step = video.steps_per_frame * video.timestep
        released = release_frame(params["hold"], video)

        def ready(sim: Simulation, frame: int) -> bool:
            if not released < frame <= video.num_frames - 3:
                return False
            bottom = _block_bottom(sim)
            if variant == "standard":
                return bottom < rim
            # The last frame before the block's free fall reaches the support.
            speed = float(sim.data.qvel[sim.model.joint("block_joint").dofadr[0] + 2])
            next_bottom = bottom + speed * step - GRAVITY * step**2 / 2
            support = params["support"]
            return bottom > support + 0.005 and (bottom < rim or next_bottom < support + 0.02)

        manipulate = _fall_through if variant == "standard" else _make_solid
        consistent, inconsistent, frame = record_pair_when(
            sim, manipulate, ready, script=release_script(sim, released)
        )
        if variant == "standard":
            manipulated = block_id
            for t in range(frame, video.num_frames):
                extra = (inconsistent[1][t] == block_id) & (consistent[1][t] != block_id)
                if extra.sum() > PENETRATION_TOLERANCE:
                    raise RejectedSample("the block's fall through the container shows")
            shown, gone = consistent[1][-1], inconsistent[1][-1]
        else:
            manipulated = sim.mask_id("support")
            if (consistent[1] == manipulated).any() or (inconsistent[1] == manipulated).any():
                raise RejectedSample("the hidden support shows")
            shown, gone = inconsistent[1][-1], consistent[1][-1]
        if (shown == block_id).sum() < 6:
            raise RejectedSample("the protruding block is hidden: the pair would not differ")
        if block_id in visible_ids(gone):
            raise RejectedSample("the block that should be out of view is seen at the end")
        return specs.probe_record(
            consistent, inconsistent, camera.as_array(), specs.CONCEPTS.index(CONCEPT),
            specs.VARIANTS.index(variant), frame, seed, [manipulated],
        )

    return draw_until_valid(make, rng)


def _behind_container(rng: np.random.Generator, box: dict, block: dict, camera: CameraPose):
    """A floor position for ``block`` behind the container as the camera sees it: along the
    line of sight, just past where the block's footprint clears the container."""
    view = np.deg2rad(camera.azimuth)
    along = np.array([np.cos(view), np.sin(view)])
    across = np.array([-along[1], along[0]])
    start = along * box["inner_y"] + across * rng.uniform(-0.5, 0.5) * box["inner_x"]
    radius = float(np.hypot(*block["half"][:2]))
    behind = 0.0
    while _outer_gap(box, start + behind * along) <= radius:
        behind += 0.02
    return start + (behind + rng.uniform(0.03, 0.15)) * along


def _outer_gap(box: dict, xy) -> float:
    """Distance from ``xy`` to the container's outer footprint (0 inside it)."""
    outer_x, outer_y = box["inner_x"] + 2 * box["wall"], box["inner_y"] + 2 * box["wall"]
    return float(np.hypot(max(abs(xy[0]) - outer_x, 0.0), max(abs(xy[1]) - outer_y, 0.0)))


def _hidden_by_container(
    eye: np.ndarray, box: dict, points: np.ndarray, margin: float = 0.03
) -> bool:
    """Whether the segment from ``eye`` to every point [N, 3] passes through the container's
    outer box (shrunk by ``margin``): an open box hides what lies behind it like a solid one."""
    half = np.array([box["inner_x"] + 2 * box["wall"], box["inner_y"] + 2 * box["wall"]]) - margin
    low = np.array([-half[0], -half[1], 0.0])
    high = np.array([half[0], half[1], box["height"] - margin])
    for point in points:
        direction = point - eye
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (low - eye) / direction, (high - eye) / direction
        near = np.nanmax(np.minimum(t1, t2))
        far = np.nanmin(np.maximum(t1, t2))
        if not (near <= far and 0.0 < far and near < 1.0):
            return False
    return True


def clip(kind: str, seed: int, video: VideoOptions) -> TensorDict:
    """A training clip: ``example`` (a block of any height drops into the container, seen from
    any perspective), ``no_object`` (the container alone) or ``object_behind_container`` (the
    block falls behind the container and ends hidden by it)."""
    if kind not in CLIP_KINDS:
        raise ValueError(f"unknown {CONCEPT} clip kind {kind!r}; valid: {', '.join(CLIP_KINDS)}")
    rng = rng_for(seed, CONCEPT, kind)

    def make(rng: np.random.Generator) -> TensorDict:
        params = draw_example(rng)
        box, block, camera = params["box"], params["block"], params["camera"]
        container_color, block_color = distinct_colors(rng, 2)
        builder = SceneBuilder(rng, video, camera)
        _add_container(builder, box, container_color)
        drop = box["height"] + params["drop"]
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
                if _hidden_by_container(eye, box, points):
                    break
                block = _draw_block(rng, box, EXAMPLE_HEIGHTS)
            else:
                raise RejectedSample("no block hides behind the container from this camera")
            _add_block(builder, block, xy, drop, block_color)
        sim = builder.build()
        script = None
        if kind != "no_object":
            script = release_script(sim, release_frame(params["hold"], video))
        frames, masks, objects = sim.record(video.num_frames, script)
        if kind != "no_object" and sim.mask_id("block") not in visible_ids(masks[0]):
            raise RejectedSample("the block is not seen before it falls")
        if kind == "object_behind_container" and sim.mask_id("block") in visible_ids(
            masks[-1]
        ):
            raise RejectedSample("the block behind the container is still seen at the end")
        return specs.clip_record(
            frames, masks, camera.as_array(), specs.CONCEPTS.index(CONCEPT),
            specs.CLIP_KINDS.index(kind), seed, objects,
        )

    return draw_until_valid(make, rng)
