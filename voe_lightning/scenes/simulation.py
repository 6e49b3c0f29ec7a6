"""A compiled scene in time: ``Simulation`` steps the physics, moves, removes and recolours
objects (scripts and hidden "magic"), forks an independent twin for a probe's inconsistent
branch, and renders frames, object-id masks and the objects' states (``specs.objects_spec``)."""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import cast

import mujoco
import numpy as np

from voe_lightning import specs
from voe_lightning.scenes.appearance import SHAPE_LABELS, rgba
from voe_lightning.scenes.camera import CameraPose, VideoOptions
from voe_lightning.scenes.depth import depth_measures
from voe_lightning.scenes.rendering import get_renderer


@dataclass
class SceneObject:
    """A named object of a scene and the mask id its pixels carry."""

    name: str
    mask_id: int
    free: bool
    mocap: bool
    geom_names: list[str] = field(default_factory=list)


#: What ``Simulation.get_state`` saves: everything the integrator needs to continue alike.
STATE_KIND = mujoco.mjtState.mjSTATE_INTEGRATION


class Simulation:
    """A compiled scene stepping through time, rendering frames and object-id masks."""

    def __init__(
        self,
        model: mujoco.MjModel,
        objects: dict[str, SceneObject],
        video: VideoOptions,
        camera: CameraPose,
    ):
        self.model = model
        self.data = mujoco.MjData(model)
        self.objects = objects
        self.video = video
        self.camera = camera
        #: Optional ``controller(sim)`` run before every physics step, for smooth scripted motion
        #: of mocap bodies (screens, rods); ``sim.data.time`` gives the time.
        self.controller: Callable[[Simulation], None] | None = None
        self.geom_mask_id = np.zeros(model.ngeom + 1, np.uint8)  # index -1 -> background
        for obj in objects.values():
            for geom_name in obj.geom_names:
                self.geom_mask_id[model.geom(geom_name).id] = obj.mask_id
        #: Objects taken out of the scene by ``remove``, with what ``restore`` puts back.
        self.removed: dict[str, _Removed] = {}
        self.boxes = {name: bounding_box(model, obj) for name, obj in objects.items()}
        mujoco.mj_forward(model, self.data)

    # --- state manipulation (used by scripts and by hidden "magic") ---------------------------
    def mask_id(self, name: str) -> int:
        return self.objects[name].mask_id

    def position(self, name: str) -> np.ndarray:
        return cast(np.ndarray, self.data.body(name).xpos.copy())

    def move(
        self,
        name: str,
        pos: Sequence[float] | np.ndarray,
        quat: Sequence[float] | np.ndarray | None = None,
    ) -> None:
        """Place a free body (velocity zeroed) or a mocap body at ``pos``."""
        obj = self.objects[name]
        if obj.mocap:
            mocap_id = self.model.body(name).mocapid[0]
            self.data.mocap_pos[mocap_id] = pos
            if quat is not None:
                self.data.mocap_quat[mocap_id] = quat
        elif obj.free:
            joint = self.model.joint(f"{name}_joint")
            qpos, qvel = joint.qposadr[0], joint.dofadr[0]
            self.data.qpos[qpos : qpos + 3] = pos
            if quat is not None:
                self.data.qpos[qpos + 3 : qpos + 7] = quat
            self.data.qvel[qvel : qvel + 6] = 0.0
        else:
            raise ValueError(f"object {name!r} is fixed and cannot be moved")
        mujoco.mj_forward(self.model, self.data)

    def set_velocity(
        self, name: str, linear: Sequence[float], angular: Sequence[float] = (0.0, 0.0, 0.0)
    ) -> None:
        joint = self.model.joint(f"{name}_joint")
        dof = joint.dofadr[0]
        self.data.qvel[dof : dof + 3] = linear
        self.data.qvel[dof + 3 : dof + 6] = angular

    def remove(self, name: str) -> None:
        """Take an object out of the scene: park it far outside the view, where it touches
        nothing (a free body stops colliding and floats); it has no object states until
        ``restore`` puts it back."""
        if name in self.removed:
            raise ValueError(f"object {name!r} is already removed")
        obj, body = self.objects[name], self.model.body(name).id
        geoms = [self.model.geom(geom_name) for geom_name in obj.geom_names]
        self.removed[name] = _Removed(
            self.data.xpos[body].copy(),
            self.data.xquat[body].copy(),
            [(int(geom.contype[0]), int(geom.conaffinity[0])) for geom in geoms],
            float(self.model.body_gravcomp[body]),
        )
        self.move(name, (60.0 + 4.0 * body, 60.0, 1.0))
        if obj.free:
            for geom in geoms:
                geom.contype = geom.conaffinity = 0
            self.model.body_gravcomp[body] = 1.0

    def restore(self, name: str) -> None:
        """Put an object that ``remove`` took out back where it was (at rest), colliding and
        weighing as before; nothing to do for an object in the scene."""
        removed = self.removed.pop(name, None)
        if removed is None:
            return
        for geom_name, (contype, conaffinity) in zip(self.objects[name].geom_names, removed.bits):
            self.model.geom(geom_name).contype = contype
            self.model.geom(geom_name).conaffinity = conaffinity
        self.model.body_gravcomp[self.model.body(name).id] = removed.gravcomp
        self.move(name, removed.position, removed.quat)

    def set_color(self, name: str, color: str | Sequence[float]) -> None:
        for geom_name in self.objects[name].geom_names:
            self.model.geom(geom_name).rgba = rgba(color)

    def step(self, num_steps: int = 1) -> None:
        if self.controller is None:
            mujoco.mj_step(self.model, self.data, num_steps)
            return
        for _ in range(num_steps):
            self.controller(self)
            mujoco.mj_step(self.model, self.data)

    def get_state(self) -> np.ndarray:
        """The full integration state (positions, velocities, mocap, warm start)."""
        state = np.empty(mujoco.mj_stateSize(self.model, STATE_KIND))
        mujoco.mj_getState(self.model, self.data, state, STATE_KIND)
        return state

    def set_state(self, state: np.ndarray) -> None:
        """Put the simulation into a state saved by ``get_state`` (derived quantities too)."""
        mujoco.mj_setState(self.model, self.data, state, STATE_KIND)
        mujoco.mj_forward(self.model, self.data)

    def fork(self) -> Simulation:
        """An independent copy (model included) in the same state, for the inconsistent branch."""
        twin = Simulation.__new__(Simulation)
        twin.model = copy.copy(self.model)
        twin.data = mujoco.MjData(twin.model)
        twin.set_state(self.get_state())
        twin.objects, twin.video, twin.camera = self.objects, self.video, self.camera
        twin.geom_mask_id, twin.controller = self.geom_mask_id, self.controller
        twin.removed, twin.boxes = dict(self.removed), self.boxes
        return twin

    # --- rendering ------------------------------------------------------------------------------
    def render(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The current RGB frame, its object-id mask (0 = background and fixed scenery) and the
        objects' states (``object_states``) with what the depth image shows of each id
        (``depth_measures``, the record's ``depth``). Poses are refreshed first: after ``mj_step`` the
        drawn poses are one step old, while a forked twin's are current, which would make a
        probe pair differ at the fork."""
        mujoco.mj_forward(self.model, self.data)
        renderer = get_renderer(self.video.height, self.video.width)
        rgb, geom_ids, depth = renderer.render(self.model, self.data, self.camera)
        mask = self.geom_mask_id[geom_ids]
        states = self.object_states(mask)
        states["depth"] = depth_measures(mask, depth)
        return rgb, mask, states

    def object_states(self, mask: np.ndarray) -> np.ndarray:
        """The states of the objects in the scene (not removed), one slot per mask id
        ([OBJECT_SLOTS] of ``specs.OBJECT_STATE_DTYPE``, see ``specs.objects_spec``): pose from
        the current data (centre of the body-frame box), box and shape from the model, colour
        from the geoms' rgba (``set_color`` changes it), and the share of ``mask``'s pixels
        showing the id. Only one object in the scene may hold an id at a time."""
        states = np.zeros(specs.OBJECT_SLOTS, specs.OBJECT_STATE_DTYPE)
        visible = np.bincount(mask.ravel(), minlength=specs.OBJECT_SLOTS) / mask.size
        for name, obj in self.objects.items():
            if name in self.removed:
                continue
            slot = obj.mask_id
            if states["shape_label"][slot]:
                raise RuntimeError(f"two objects in the scene hold mask id {slot}")
            centre, half, label = self.boxes[name]
            body = self.data.body(name)
            states["position"][slot] = body.xpos + body.xmat.reshape(3, 3) @ centre
            states["orientation"][slot] = body.xquat
            states["size"][slot] = half
            states["shape_label"][slot] = label
            states["color"][slot] = self.model.geom(obj.geom_names[0]).rgba[:3]
            states["visible_fraction"][slot] = visible[slot]
        return states

    def record(
        self,
        num_frames: int,
        script: Callable[[Simulation, int], None] | None = None,
        first_frame: int = 0,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Render ``num_frames`` frames, stepping one frame interval after each: (frames, masks,
        object states) as ``render`` gives them, stacked over time.
        ``script(sim, frame_index)`` runs before each frame is rendered (scripted motion)."""
        shape = (num_frames, self.video.height, self.video.width)
        frames, masks = np.empty((*shape, 3), np.uint8), np.empty(shape, np.uint8)
        objects = np.empty((num_frames, specs.OBJECT_SLOTS), specs.OBJECT_STATE_DTYPE)
        for offset in range(num_frames):
            if script is not None:
                script(self, first_frame + offset)
            frames[offset], masks[offset], objects[offset] = self.render()
            self.step(self.video.steps_per_frame)
        return frames, masks, objects


@dataclass(frozen=True)
class _Removed:
    """What ``Simulation.remove`` changed about an object, for ``restore``: its pose, its
    geoms' collision bits and its body's gravity compensation."""

    position: np.ndarray
    quat: np.ndarray
    bits: list[tuple[int, int]]
    gravcomp: float


def bounding_box(model: mujoco.MjModel, obj: SceneObject) -> tuple[np.ndarray, np.ndarray, int]:
    """Centre and half-extents, in its body frame, of the box that holds all of ``obj``'s geoms
    (each geom's own box, MuJoCo's ``geom_aabb``, turned into the body frame), and its
    ``objects/shape_label``: its geom's shape, or ``compound`` for several geoms."""
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    rotation = np.empty(9)
    for geom_name in obj.geom_names:
        geom = model.geom(geom_name)
        mujoco.mju_quat2Mat(rotation, geom.quat)
        turn = rotation.reshape(3, 3)
        aabb = model.geom_aabb[geom.id]
        centre, half = geom.pos + turn @ aabb[:3], np.abs(turn) @ aabb[3:]
        low, high = np.minimum(low, centre - half), np.maximum(high, centre + half)
    if len(obj.geom_names) == 1:
        label = SHAPE_LABELS[int(model.geom(obj.geom_names[0]).type[0])]
    else:
        label = specs.OBJECT_SHAPES.index("compound")
    return (low + high) / 2, (high - low) / 2, label


def visible_ids(mask: np.ndarray) -> set[int]:
    """Mask ids with at least one pixel in ``mask``."""
    return set(np.unique(mask).tolist()) - {0}
