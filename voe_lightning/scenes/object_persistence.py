"""Object persistence (paper §3, after Baillargeon 1985): a rigid plank falls on an object.
Consistent probes end with the plank propped up on the object it hides; inconsistent ones end
with the plank flat, the object removed while the plank hid it. Counterbalanced probes start
empty: the plank falls flat (consistent) or ends propped on an object that appeared under it
while hidden (inconsistent). The two are one quadruplet per seed: the same plank's fall with and
without the object, spliced where the plank hides its place, so that after the change each
inconsistent video is exactly the other variant's consistent one. Examples vary object, plank and poses freely; controls drop the
plank on open floor beside a visible object, or on an empty floor. Every clip starts at a random
phase of the first frame interval, so that a probe can place its hidden change exactly at a
frame (frames identical through the manipulation) without starting unlike the examples."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any, cast

import mujoco
import numpy as np
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes import recording
from voe_lightning.scenes.appearance import distinct_colors
from voe_lightning.scenes.builder import SceneBuilder, yaw_quat
from voe_lightning.scenes.camera import CameraPose, CameraRange, VideoOptions, accept_any_video
from voe_lightning.scenes.recording import (
    Video,
    draw_clip,
    join,
    quadruplet_record,
    record_with_ghost,
)
from voe_lightning.scenes.sampling import RejectedSample, draw_until_valid, rng_for
from voe_lightning.scenes.simulation import Simulation, visible_ids

CONCEPT = "object_persistence"
#: Its scenes render videos of any size and length (``scenes.check_video``).
check_video = accept_any_video
#: One camera distribution for examples, controls and probes (docs/architecture.md §4, "one world"); the
#: scene is placed relative to where the camera looks (``_anchor``).
CAMERA = CameraRange(
    lookat_x=(-0.4, 0.4),
    lookat_y=(-0.6, 0.4),
    lookat_z=(0.35, 0.5),
    distance=(3.5, 4.8),
    azimuth=(55.0, 125.0),
    elevation=(-38.0, -20.0),
)
#: Probes look along the plank (it must face the camera to hide what is under it): a
#: controlled view inside CAMERA.
PROBE_CAMERA = CAMERA.narrow(azimuth=(84.0, 96.0), elevation=(-32.0, -22.0))
#: Where the object stands relative to the camera's look-at point (x, y ranges): examples and
#: controls anywhere in this box, probes in the middle of it.
ANCHOR_OFFSET = ((-0.25, 0.25), (0.2, 0.6))
PROBE_ANCHOR_OFFSET = ((-0.2, 0.2), (0.4, 0.55))
#: Longest plank half side and drop height (lowest point above the object's top, in controls
#: the top of an object of the drawn size) of training clips; probes draw inside these.
PLANK_HALF_LENGTH = (0.3, 1.6)
DROP_HEIGHT = (0.2, 1.4)


def _quat(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    quat = np.empty(4)
    mujoco.mju_axisAngle2Quat(quat, np.asarray(axis, float), angle)
    return quat


def _compose(*quats: np.ndarray) -> np.ndarray:
    """The rotation applying the last quaternion first (q1 * q2 * ...)."""
    result = np.array([1.0, 0.0, 0.0, 0.0])
    for quat in quats:
        mujoco.mju_mulQuat(result, result.copy(), quat)
    return result


def _rotate(quat: np.ndarray, vector: Sequence[float] | np.ndarray) -> np.ndarray:
    out = np.empty(3)
    mujoco.mju_rotVecQuat(out, np.asarray(vector, float), quat)
    return out


def _draw_object(rng: np.random.Generator, sizes: tuple[float, float]) -> dict[str, Any]:
    """A sphere (radius) or cube (half side) of random size and yaw."""
    shape = "sphere" if rng.random() < 0.5 else "box"
    half = float(rng.uniform(*sizes))
    return {"shape": shape, "half": half, "yaw": float(rng.uniform(0, np.pi / 2))}


def _add_object(
    builder: SceneBuilder, obj: dict[str, Any], xy: Sequence[float] | np.ndarray, color: str
) -> None:
    size = [obj["half"]] if obj["shape"] == "sphere" else [obj["half"]] * 3
    builder.add_primitive(
        "object",
        obj["shape"],
        size,
        [xy[0], xy[1], obj["half"]],
        color,
        quat=yaw_quat(obj["yaw"]),
        density=1500.0,
        friction=1.5,
    )
    if obj["shape"] == "sphere":  # rolling resistance: a propped sphere creeps less
        geom = builder.spec.geom("object_0")
        geom.condim = 6
        geom.friction = [1.5, 0.005, 0.02]


def _add_plank(
    builder: SceneBuilder,
    half_sizes: Sequence[float] | np.ndarray,
    center: Sequence[float] | np.ndarray,
    quat: Sequence[float] | np.ndarray,
    color: str,
) -> None:
    builder.add_primitive(
        "plank", "box", list(half_sizes), list(center), color, quat=list(quat), friction=2.0
    )


def _anchor(
    rng: np.random.Generator,
    camera: CameraPose,
    offset: tuple[tuple[float, float], tuple[float, float]],
) -> np.ndarray:
    """The floor point (x, y) the scene is built around, drawn relative to the camera."""
    (x_low, x_high), (y_low, y_high) = offset
    return cast(
        np.ndarray,
        np.array(camera.lookat[:2]) + (rng.uniform(x_low, x_high), rng.uniform(y_low, y_high)),
    )


def _plank_lowest_point(sim: Simulation) -> float:
    """Height of the plank's lowest corner above the floor."""
    geom = sim.data.geom("plank_0")
    half = sim.model.geom("plank_0").size
    rotation = geom.xmat.reshape(3, 3)
    return float(geom.xpos[2] - np.abs(rotation[2]) @ half)


def _touching(sim: Simulation, first: str, second: str, depth: float = 0.0) -> bool:
    """Whether geoms ``first`` and ``second`` are in contact (penetrating deeper than ``depth``)."""
    ids = {sim.model.geom(first).id, sim.model.geom(second).id}
    contacts = sim.data.contact[: sim.data.ncon]
    return any({c.geom1, c.geom2} == ids and c.dist < -depth for c in contacts)


# --- probes --------------------------------------------------------------------------------------


def probe_layout(rng: np.random.Generator) -> dict[str, Any]:
    """A probe's geometry: the plank, pitched front-down and facing the camera, drops so that its
    front edge lands in front of the object and it pivots back to rest on the object, which its
    sloped underside then hides (the camera looks along the plank from a low elevation). At the
    start it hangs high enough for the camera to see the object under it."""
    camera = PROBE_CAMERA.sample(rng)
    obj = _draw_object(rng, (0.22, 0.36))
    if obj["shape"] == "box":
        obj["half"] *= 0.85
    half = obj["half"]
    # The plank covers the object's footprint: corners of a yawed cube reach half * sqrt(2).
    reach = half * (np.sqrt(2) if obj["shape"] == "box" else 1.0)
    # Contact at u = ratio * half length from the front edge: behind the plank's middle, so the
    # plank stays propped, with enough plank beyond it to cover the object.
    ratio = float(rng.uniform(1.12, 1.35))
    shortest = max(0.8, (1.6 * reach + 0.1) / (2 - ratio))
    half_length = float(rng.uniform(shortest, min(shortest + 0.35, PLANK_HALF_LENGTH[1])))
    contact = ratio * half_length
    obj_xy = _anchor(rng, camera, PROBE_ANCHOR_OFFSET)
    if obj["shape"] == "sphere":
        front_y = obj_xy[1] - contact
        rest_pitch = 2 * np.arctan(half / contact)
    else:
        front_y = obj_xy[1] - reach - np.sqrt(contact**2 - (2 * half) ** 2)
        rest_pitch = np.arcsin(2 * half / contact)
    half_width = float(rng.uniform(reach + 0.3, max(reach + 0.3, 1.0)))
    half_thickness = float(rng.uniform(0.02, 0.05))
    pitch = rest_pitch + np.deg2rad(rng.uniform(12, 24))
    quat = _compose(
        _quat((0, 0, 1), np.deg2rad(rng.uniform(-3, 3))),
        _quat((1, 0, 0), pitch),
    )
    # High enough that the line of sight to the object's top passes under the front edge.
    clearance = (obj_xy[1] - reach - front_y) * np.tan(np.deg2rad(-camera.elevation))
    drop = clearance + rng.uniform(0.1, 0.3)
    if not DROP_HEIGHT[0] <= drop <= DROP_HEIGHT[1]:
        raise RejectedSample(f"the plank would start {drop:.2f} m above the object")
    front = np.array([obj_xy[0] + rng.uniform(-0.04, 0.04), front_y, 2 * half + drop])
    center = front - _rotate(quat, (0.0, -half_length, -half_thickness))
    return {
        "object": obj,
        "object_xy": obj_xy,
        "plank_half": (half_width, half_length, half_thickness),
        "plank_center": center,
        "plank_quat": quat,
        "drop": float(drop),
        "camera": camera,
    }


def _change_step(sim: Simulation, rng: np.random.Generator, last_frame: int) -> int:
    """A physics step after which the object can appear or vanish unseen, drawn at random from
    all such steps: the plank's front edge has landed, the plank does not touch the object's
    place yet (so the plank moves the same with and without the object) and hides it. Found on
    a copy holding the object in place (put back, if removed); raises RejectedSample when there
    is none."""
    dry = sim.fork()
    dry.restore("object")
    plank, obj = sim.model.geom("plank_0").id, sim.model.geom("object_0").id
    spf = sim.video.steps_per_frame
    fromto = np.empty(6)
    candidates: list[tuple[int, Simulation]] = []
    for step in range(1, (last_frame + 1) * spf):
        dry.step(1)
        mujoco.mj_forward(dry.model, dry.data)
        if step < spf or _plank_lowest_point(dry) >= 0.02:
            continue
        if mujoco.mj_geomDistance(dry.model, dry.data, plank, obj, 0.01, fromto) < 0.004:
            break  # the plank reaches the object: the two branches would differ from here on
        candidates.append((step, dry.fork()))
    index: np.int64  # numpy's stubs give an array's items as Any
    for index in rng.permutation(len(candidates)):
        step, state = candidates[index]
        if sim.mask_id("object") not in visible_ids(state.render()[1]):
            return step
    raise RejectedSample("no moment where the plank hides the object's place before touching it")


def probe(variant: str, seed: int, video: VideoOptions) -> TensorDict:
    """A probe pair of ``variant``, one half of the seed's quadruplet (``quadruplet``):
    ``standard`` (the object vanishes under the plank) or ``counterbalanced`` (the scene starts
    empty and an object appears under the plank); after the change each pair's inconsistent
    video is exactly the other's consistent one."""
    specs.check_variant(CONCEPT, variant)
    return quadruplet_record(CONCEPT, variant, seed, quadruplet(seed, video))


@functools.lru_cache(maxsize=4)
def quadruplet(seed: int, video: VideoOptions) -> recording.Quadruplet:
    """One scene draw's quadruplet: ((A, AB), (B, BA)) with A the plank ending propped on the
    object and B the same plank's fall in the scene without the object (A's motion: the change
    comes before the plank touches the object's place), spliced at a frame where the plank
    hides that place (``recording.quadruplet``); with the camera, that frame and the object's
    mask id. Cached, as both variants of a seed read it (callers copy what they keep)."""
    rng = rng_for(seed, CONCEPT, "quadruplet")

    def make(rng: np.random.Generator) -> recording.Quadruplet:
        layout = probe_layout(rng)
        plank_color, object_color = distinct_colors(rng, 2)
        builder = SceneBuilder(rng, video, layout["camera"])
        _add_object(builder, layout["object"], layout["object_xy"], object_color)
        _add_plank(
            builder, layout["plank_half"], layout["plank_center"], layout["plank_quat"], plank_color
        )
        sim = builder.build()
        object_id = sim.mask_id("object")
        # The change happens at physics step ``step``: start the video that many steps into a
        # frame interval (as every clip starts at a random phase) so that it falls on a frame.
        step = _change_step(sim, rng, last_frame=video.num_frames - 3)
        frame, phase = divmod(step, video.steps_per_frame)
        sim.step(phase)
        present, absent = record_with_ghost(sim, frame, lambda ghost: ghost.remove("object"))
        empty = sim.fork()
        empty.remove("object")
        rest = video.num_frames - frame
        present = join(present, sim.record(rest, first_frame=frame))
        absent = join(absent, empty.record(rest, first_frame=frame))
        if object_id not in visible_ids(present[1][0]):
            raise RejectedSample("the object is hidden before the plank falls")
        if any(object_id in visible_ids(mask) for mask in present[1][frame:]):
            raise RejectedSample("the object shows from under the propped plank")
        pairs = recording.quadruplet(present, absent, frame)
        return pairs, layout["camera"].as_array(), frame, object_id

    return draw_until_valid(make, rng)


# --- training clips --------------------------------------------------------------------------


def _random_plank(
    rng: np.random.Generator, above: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Plank half sizes (width, length and thickness vary greatly) and a random pose whose
    lowest corner starts ``above`` metres over the floor; centred at the origin in xy."""
    half = np.array(
        [rng.uniform(0.3, 1.1), rng.uniform(*PLANK_HALF_LENGTH), rng.uniform(0.02, 0.06)]
    )
    quat = _compose(
        _quat((0, 0, 1), rng.uniform(-np.pi, np.pi)),
        _quat((0, 1, 0), np.deg2rad(rng.uniform(-30, 30))),
        _quat((1, 0, 0), np.deg2rad(rng.uniform(-70, 70))),
    )
    rotation = np.empty(9)
    mujoco.mju_quat2Mat(rotation, quat)
    depth = float(np.abs(rotation.reshape(3, 3)[2]) @ half)
    return half, quat, np.array([0.0, 0.0, above + depth]), float(np.hypot(half[0], half[1]))


def clip_layout(rng: np.random.Generator, kind: str) -> dict[str, Any]:
    """A training clip's geometry (the keys of ``probe_layout``): camera from CAMERA, object and
    plank around a point drawn relative to it; the plank over the object (``example``) or on
    open floor beside it (controls)."""
    camera = CAMERA.sample(rng)
    obj = _draw_object(rng, (0.15, 0.4))
    anchor = _anchor(rng, camera, ANCHOR_OFFSET)
    drop = float(rng.uniform(*DROP_HEIGHT))
    # Every kind drops the plank from over the drawn object's top, whether or not the object
    # ends up under it: were the controls' planks dropped from lower, a plank's height alone
    # would tell a learner whether it will land on something (a counterbalanced probe's plank
    # falls from an example's height onto an empty floor).
    plank_half, plank_quat, plank_center, plank_radius = _random_plank(
        rng, above=2 * obj["half"] + drop
    )
    if kind == "example":
        # Somewhere over the object, so that the plank hits it.
        obj_xy = anchor
        offset = rng.uniform(-0.5, 0.5, size=2) * plank_half[:2]
        plank_center[:2] = obj_xy + _rotate(plank_quat, (*offset, 0.0))[:2]
    else:
        # Open floor beside the object: beyond the plank's reach (draws where it still touches
        # the object are rejected by ``clip``); the pair (or the plank alone) around the anchor.
        angle = rng.uniform(-np.pi, np.pi)
        distance = plank_radius + obj["half"] * np.sqrt(2) + rng.uniform(0.15, 0.5)
        step = distance * np.array([np.cos(angle), np.sin(angle)])
        beside = kind == "plank_beside_object"
        obj_xy = anchor - step / 2 if beside else anchor - step
        plank_center[:2] = obj_xy + step
    return {
        "object": obj,
        "object_xy": obj_xy,
        "plank_half": tuple(plank_half),
        "plank_center": plank_center,
        "plank_quat": plank_quat,
        "drop": drop,
        "camera": camera,
    }


def clip(kind: str, seed: int, video: VideoOptions) -> TensorDict:
    """A training clip: ``example`` (the plank falls on a sphere or cube; poses, sizes and
    camera vary), ``plank_beside_object`` (it lands on open floor beside a visible object) or
    ``plank_on_empty_floor`` (no object at all)."""

    def draw_scene(rng: np.random.Generator) -> tuple[CameraPose, Video]:
        plank_color, object_color = distinct_colors(rng, 2)
        layout = clip_layout(rng, kind)
        obj, obj_xy, camera = layout["object"], layout["object_xy"], layout["camera"]
        builder = SceneBuilder(rng, video, camera)
        if kind != "plank_on_empty_floor":
            _add_object(builder, obj, obj_xy, object_color)
        _add_plank(
            builder, layout["plank_half"], layout["plank_center"], layout["plank_quat"], plank_color
        )
        sim = builder.build()
        sim.step(int(rng.integers(video.steps_per_frame)))  # a random phase, as probes have
        frames, masks, objects = sim.record(video.num_frames)
        if kind == "plank_beside_object":
            pushed = np.linalg.norm(sim.position("object")[:2] - obj_xy) > 0.005
            if pushed or _touching(sim, "object_0", "plank_0"):
                raise RejectedSample("the plank touched the object")
            if sim.mask_id("object") not in visible_ids(masks[-1]):
                raise RejectedSample("the plank hid the object")
        if sim.mask_id("plank") not in visible_ids(masks[-1]):
            raise RejectedSample("the plank landed out of view")
        return camera, (frames, masks, objects)

    return draw_clip(CONCEPT, kind, seed, draw_scene)
