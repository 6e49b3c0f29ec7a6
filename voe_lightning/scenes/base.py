"""What every concept's scene shares: an MjSpec scene builder with named, mask-labelled objects,
a per-process renderer that reuses one GL context, a simulation that renders frames and masks
and can fork at a hidden manipulation."""

from __future__ import annotations

import copy
import hashlib
import importlib
import math
import os
from dataclasses import dataclass, field
from typing import Callable, Sequence

import mujoco
import numpy as np
from tensordict import TensorDict

from voe_lightning import specs

SHAPES = {
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
    "capsule": mujoco.mjtGeom.mjGEOM_CAPSULE,
    "ellipsoid": mujoco.mjtGeom.mjGEOM_ELLIPSOID,
}
#: ``objects/shape_label`` of an object of one geom, by MuJoCo geom type.
SHAPE_LABELS = {int(geom_type): specs.OBJECT_SHAPES.index(name) for name, geom_type in SHAPES.items()}

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

#: Floor textures shared by every model, so one GPU context serves all scenes (see Renderer).
_FLOOR_TEXTURES = ("checker", "gradient", "flat")


@dataclass(frozen=True)
class VideoOptions:
    """Geometry and timing of a rendered video (paper: 15 frames, 64x64, about 3 s)."""

    num_frames: int = specs.NUM_FRAMES
    height: int = specs.HEIGHT
    width: int = specs.WIDTH
    duration: float = 3.0
    timestep: float = 0.01

    def __post_init__(self) -> None:
        for name in ("num_frames", "height", "width"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not 0 < self.timestep <= self.duration / self.num_frames:
            raise ValueError(
                f"timestep {self.timestep} must be in (0, duration/num_frames="
                f"{self.duration / self.num_frames:g}]"
            )

    @property
    def steps_per_frame(self) -> int:
        return max(1, round(self.duration / self.num_frames / self.timestep))


@dataclass(frozen=True)
class CameraPose:
    """A free camera looking at ``lookat`` from ``distance`` at ``azimuth``/``elevation`` (deg)."""

    lookat: tuple[float, float, float] = (0.0, 0.0, 0.4)
    distance: float = 4.0
    azimuth: float = 90.0
    elevation: float = -20.0

    def as_array(self) -> np.ndarray:
        return np.array([*self.lookat, self.distance, self.azimuth, self.elevation], np.float32)


@dataclass(frozen=True)
class CameraRange:
    """One concept's camera distribution: each pose parameter uniform in its (low, high).
    Examples, every control and the probes of a concept draw from it (docs/architecture.md §4, "one
    world"); probes may draw from a narrower range that lies inside it (``narrow``)."""

    lookat_x: tuple[float, float]
    lookat_y: tuple[float, float]
    lookat_z: tuple[float, float]
    distance: tuple[float, float]
    azimuth: tuple[float, float]
    elevation: tuple[float, float]

    def __post_init__(self) -> None:
        for name, (low, high) in self.ranges().items():
            if not low <= high:
                raise ValueError(f"camera range {name} must have low <= high, got ({low}, {high})")

    def ranges(self) -> dict[str, tuple[float, float]]:
        """The (low, high) of each parameter, in the order of ``CameraPose.as_array``."""
        return {name: getattr(self, name) for name in CAMERA_PARAMETERS}

    def sample(self, rng: np.random.Generator) -> CameraPose:
        x, y, z, distance, azimuth, elevation = (
            float(rng.uniform(low, high)) for low, high in self.ranges().values()
        )
        return CameraPose((x, y, z), distance, azimuth, elevation)

    def contains(self, camera: CameraPose | np.ndarray, tolerance: float = 1e-4) -> bool:
        """Whether a pose (or a ``[..., 6]`` array of poses) lies inside every range."""
        values = np.asarray(camera.as_array() if isinstance(camera, CameraPose) else camera)
        low, high = np.array(list(self.ranges().values()), np.float64).T
        return bool(((values >= low - tolerance) & (values <= high + tolerance)).all())

    def narrow(self, **ranges: tuple[float, float]) -> "CameraRange":
        """A sub-range for probes; refuses a range that leaves this one."""
        for name, (low, high) in ranges.items():
            outer_low, outer_high = self.ranges()[name]
            if low < outer_low or high > outer_high:
                raise ValueError(
                    f"probe camera {name} range ({low}, {high}) leaves the training range "
                    f"({outer_low}, {outer_high})"
                )
        return CameraRange(**{**self.ranges(), **ranges})


#: Names of the six camera parameters, in the order of ``CameraPose.as_array``.
CAMERA_PARAMETERS = ("lookat_x", "lookat_y", "lookat_z", "distance", "azimuth", "elevation")

#: Vertical field of view of MuJoCo's free camera (model default, degrees).
FOVY = 45.0


def camera_axes(camera: CameraPose) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Position, right, up and forward unit vectors of MuJoCo's free camera at ``camera``."""
    az, el = math.radians(camera.azimuth), math.radians(camera.elevation)
    forward = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    up = np.array([-math.sin(el) * math.cos(az), -math.sin(el) * math.sin(az), math.cos(el)])
    position = np.asarray(camera.lookat) - camera.distance * forward
    return position, np.cross(forward, up), up, forward


def camera_coordinates(camera: CameraPose, point) -> tuple[float, float, float]:
    """The world ``point`` in the camera's frame: its offsets along right, up and forward
    (depth); every projection of a point into the image starts here."""
    position, right, up, forward = camera_axes(camera)
    offset = np.asarray(point, float) - position
    return offset @ right, offset @ up, offset @ forward


@dataclass
class Geom:
    """One primitive of an object, placed relative to its body."""

    shape: str
    size: Sequence[float]
    pos: Sequence[float] = (0.0, 0.0, 0.0)
    quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)


@dataclass
class SceneObject:
    """A named object of a scene and the mask id its pixels carry."""

    name: str
    mask_id: int
    free: bool
    mocap: bool
    geom_names: list[str] = field(default_factory=list)


def rgba(color: str | Sequence[float], alpha: float = 1.0) -> list[float]:
    """An RGBA list from a palette name or an RGB triple."""
    rgb = PALETTE[color] if isinstance(color, str) else color
    return [*rgb, alpha]


def distinct_colors(rng: np.random.Generator, count: int) -> tuple[str, ...]:
    """``count`` different palette colour names, drawn at random."""
    return tuple(COLOR_NAMES[i] for i in rng.choice(len(COLOR_NAMES), size=count, replace=False))


def yaw_quat(angle: float) -> list[float]:
    """Quaternion of a rotation by ``angle`` radians about the vertical axis."""
    return [float(np.cos(angle / 2)), 0.0, 0.0, float(np.sin(angle / 2))]


class SceneBuilder:
    """Builds one episode with MjSpec: floor, light, camera and named objects, each object
    labelled with a mask id (1, 2, ... in the order added). An id names what a tracker would
    follow, one spatio-temporal object: a body that will be swapped in for another while
    hidden shares that one's id (``replaces``)."""

    def __init__(
        self,
        rng: np.random.Generator,
        video: VideoOptions,
        camera: CameraPose,
        floor_pattern: str | None = None,
    ):
        self.rng = rng
        self.video = video
        self.camera = camera
        self.objects: dict[str, SceneObject] = {}
        self.spec = spec = mujoco.MjSpec()
        spec.option.timestep = video.timestep
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        spec.visual.quality.shadowsize = 0  # 4096 shadows cost ~14 ms a frame under software EGL
        spec.visual.quality.offsamples = 0
        spec.visual.global_.offwidth = max(video.width, 64)
        spec.visual.global_.offheight = max(video.height, 64)
        spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
        spec.visual.headlight.diffuse = [0.45, 0.45, 0.45]
        spec.stat.extent = 6.0
        for name in _FLOOR_TEXTURES:
            builtin = {
                "checker": mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
                "gradient": mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                "flat": mujoco.mjtBuiltin.mjBUILTIN_FLAT,
            }[name]
            spec.add_texture(
                name=name,
                type=mujoco.mjtTexture.mjTEXTURE_2D,
                builtin=builtin,
                width=64,
                height=64,
                rgb1=[0.55, 0.55, 0.55],
                rgb2=[0.40, 0.40, 0.40],
            )
        pattern = floor_pattern or _FLOOR_TEXTURES[rng.integers(len(_FLOOR_TEXTURES))]
        tint = 0.75 + 0.25 * rng.random(3)
        material = spec.add_material(name="floor", rgba=[*tint, 1.0])
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = pattern
        repeat = float(rng.uniform(3, 8))
        material.texrepeat = [repeat, repeat]
        spec.worldbody.add_light(pos=[0, -1.0, 6.0], dir=[0, 0.15, -1], diffuse=[0.6, 0.6, 0.6])
        spec.worldbody.add_geom(
            name="floor",
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[20, 20, 2.0],
            material="floor",
            friction=[0.8, 0.005, 0.0001],
        )

    def add(
        self,
        name: str,
        geoms: Sequence[Geom],
        pos: Sequence[float],
        color: str | Sequence[float],
        quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
        free: bool = True,
        mocap: bool = False,
        density: float = 500.0,
        friction: float = 0.8,
        replaces: str | None = None,
    ) -> SceneObject:
        """Add an object made of ``geoms``; ``free`` bodies fall and collide, ``mocap`` bodies
        are moved by the script (screens, rods), others are fixed (pillars, walls). An object
        that ``replaces`` another (swapped in for it while hidden, never in the scene at the
        same time: ``Simulation.remove``) takes its mask id; any other gets a new one."""
        if name in self.objects:
            raise ValueError(f"object {name!r} already exists")
        if replaces is not None:
            mask_id = self.objects[replaces].mask_id
        else:
            mask_id = max((other.mask_id for other in self.objects.values()), default=0) + 1
        if mask_id > specs.MAX_OBJECT_ID:
            raise ValueError(f"a scene may hold at most {specs.MAX_OBJECT_ID} objects")
        obj = SceneObject(name, mask_id, free, mocap)
        body = self.spec.worldbody.add_body(name=name, pos=list(pos), quat=list(quat), mocap=mocap)
        if free:
            body.add_freejoint(name=f"{name}_joint")
        for index, geom in enumerate(geoms):
            geom_name = f"{name}_{index}"
            body.add_geom(
                name=geom_name,
                type=SHAPES[geom.shape],
                size=list(geom.size) + [0.0] * (3 - len(geom.size)),
                pos=list(geom.pos),
                quat=list(geom.quat),
                rgba=rgba(color),
                density=density,
                friction=[friction, 0.005, 0.0001],
            )
            obj.geom_names.append(geom_name)
        self.objects[name] = obj
        return obj

    def add_primitive(
        self, name: str, shape: str, size: Sequence[float], pos: Sequence[float], color, **kwargs
    ) -> SceneObject:
        """Add an object of one primitive geom."""
        return self.add(name, [Geom(shape, size)], pos, color, **kwargs)

    def build(self) -> "Simulation":
        """Compile the scene into a simulation at time 0."""
        model = self.spec.compile()
        return Simulation(model, self.objects, self.video, self.camera)


class Renderer:
    """Renders RGB frames and geom-id images for any model built by SceneBuilder, reusing one
    GL context, one MjrContext and one MjvScene (a new mujoco.Renderer costs ~70-100 ms).
    Valid because every such model carries the same textures and only primitive geoms."""

    def __init__(self, height: int, width: int):
        template = SceneBuilder(
            np.random.default_rng(0), VideoOptions(height=height, width=width), CameraPose()
        ).spec.compile()
        self.height, self.width = height, width
        # Choose the backend from MUJOCO_GL now, not from whatever it was when mujoco was imported.
        backend = os.environ.get("MUJOCO_GL", "egl")
        gl_context_class = importlib.import_module(f"mujoco.{backend}").GLContext
        self._gl_context = gl_context_class(max(width, 64), max(height, 64))
        self._gl_context.make_current()
        self._context = mujoco.MjrContext(template, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._context)
        self._scene = mujoco.MjvScene(template, maxgeom=500)
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), np.uint8)

    def render(
        self, model: mujoco.MjModel, data: mujoco.MjData, camera: CameraPose
    ) -> tuple[np.ndarray, np.ndarray]:
        """RGB uint8 [H, W, 3] and the id of the geom seen at each pixel (-1: none) [H, W]."""
        self._gl_context.make_current()
        self._camera.lookat[:] = camera.lookat
        self._camera.distance = camera.distance
        self._camera.azimuth = camera.azimuth
        self._camera.elevation = camera.elevation
        mujoco.mjv_updateScene(
            model, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene
        )
        mujoco.mjr_render(self._rect, self._scene, self._context)
        mujoco.mjr_readPixels(self._rgb, None, self._rect, self._context)
        rgb = np.flipud(self._rgb).copy()

        self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        try:
            mujoco.mjr_render(self._rect, self._scene, self._context)
            mujoco.mjr_readPixels(self._rgb, None, self._rect, self._context)
        finally:
            self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
            self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        seg = np.flipud(self._rgb).astype(np.int64)
        segid = seg[..., 0] + (seg[..., 1] << 8) + (seg[..., 2] << 16)
        lookup = np.full(self._scene.ngeom + 1, -1, np.int64)
        for index in range(self._scene.ngeom):
            geom = self._scene.geoms[index]
            if geom.segid != -1 and geom.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lookup[geom.segid + 1] = geom.objid
        return rgb, lookup[np.clip(segid, 0, self._scene.ngeom)]


_RENDERERS: dict[tuple[int, int, int], Renderer] = {}


def get_renderer(height: int, width: int) -> Renderer:
    """The renderer of this process for this frame size (made once per worker process)."""
    key = (os.getpid(), height, width)
    if key not in _RENDERERS:
        _RENDERERS[key] = Renderer(height, width)
    return _RENDERERS[key]


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
        self.controller: Callable[["Simulation"], None] | None = None
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
        return self.data.body(name).xpos.copy()

    def move(self, name: str, pos: Sequence[float], quat: Sequence[float] | None = None) -> None:
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

    def set_velocity(self, name: str, linear: Sequence[float], angular=(0.0, 0.0, 0.0)) -> None:
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

    def fork(self) -> "Simulation":
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
        objects' states (``object_states``). Poses are refreshed first: after ``mj_step`` the
        drawn poses are one step old, while a forked twin's are current, which would make a
        probe pair differ at the fork."""
        mujoco.mj_forward(self.model, self.data)
        renderer = get_renderer(self.video.height, self.video.width)
        rgb, geom_ids = renderer.render(self.model, self.data, self.camera)
        mask = self.geom_mask_id[geom_ids]
        return rgb, mask, self.object_states(mask)

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
        script: Callable[["Simulation", int], None] | None = None,
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


def rng_for(seed: int, *salt: str) -> np.random.Generator:
    """A generator determined by ``seed`` and names (concept, kind or variant), so that the
    same seed in different concepts or kinds gives independent draws."""
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")
    words = [
        int.from_bytes(hashlib.blake2b(word.encode(), digest_size=8).digest(), "little")
        for word in salt
    ]
    return np.random.default_rng([seed, *words, len(salt)])


class RejectedSample(Exception):
    """A random draw that does not satisfy a probe's constraints; the caller draws again."""


def draw_until_valid(
    make: Callable[[np.random.Generator], TensorDict], rng: np.random.Generator, attempts: int = 50
) -> TensorDict:
    """Call ``make(rng)`` until it does not raise RejectedSample (deterministic for one rng)."""
    last = None
    for _ in range(attempts):
        try:
            return make(rng)
        except RejectedSample as error:
            last = error
    raise RuntimeError(f"no valid scene after {attempts} draws; last rejection: {last}")


#: A rendered video: uint8 frames [T, H, W, 3], masks [T, H, W] and object states [T, OBJECT_SLOTS]
#: of ``specs.OBJECT_STATE_DTYPE``, as ``Simulation.record`` gives them.
Video = tuple[np.ndarray, np.ndarray, np.ndarray]


def splice(consistent: Video, rest: Video, manipulation_frame: int) -> Video:
    """The inconsistent video of a pair: the consistent one before ``manipulation_frame``, then
    ``rest``, rendered from the manipulated twin from that frame on. The hidden change happens
    at the manipulation frame, which renders alike in both; its object states are the
    consistent video's too, so that a pair is identical through that frame in everything a
    model may read (docs/architecture.md §7), and the states show the change from the next frame on."""
    frames, masks, objects = (
        np.concatenate([a[:manipulation_frame], b]) for a, b in zip(consistent, rest)
    )
    objects[manipulation_frame] = consistent[2][manipulation_frame]
    return frames, masks, objects


def record_pair(
    sim: Simulation,
    manipulation_frame: int,
    manipulate: Callable[[Simulation], None],
    script: Callable[[Simulation, int], None] | None = None,
    script_inconsistent: Callable[[Simulation, int], None] | None = None,
) -> tuple[Video, Video]:
    """Render a probe pair from one simulation: frames before ``manipulation_frame`` are
    rendered once and shared; then the simulation forks, ``manipulate`` applies the hidden
    change to the inconsistent branch, and both branches run to the end (``splice``)."""
    total = sim.video.num_frames
    if not 0 < manipulation_frame < total:
        raise ValueError(f"manipulation_frame must be in [1, {total - 1}], got {manipulation_frame}")
    prefix = sim.record(manipulation_frame, script)
    twin = sim.fork()
    manipulate(twin)
    rest = total - manipulation_frame
    consistent_rest = sim.record(rest, script, first_frame=manipulation_frame)
    inconsistent_rest = twin.record(
        rest, script_inconsistent or script, first_frame=manipulation_frame
    )
    consistent = tuple(np.concatenate([a, b]) for a, b in zip(prefix, consistent_rest))
    return consistent, splice(consistent, inconsistent_rest, manipulation_frame)


def record_pair_when(
    sim: Simulation,
    manipulate: Callable[[Simulation], bool | None],
    ready: Callable[[Simulation, int], bool],
    hidden_ids: Sequence[int] = (),
    script: Callable[[Simulation, int], None] | None = None,
    checks_per_frame: int = 1,
) -> tuple[Video, Video, int]:
    """Render a probe pair whose hidden change happens as soon as it can, for events whose
    timing only the physics knows (a plank landing, a block entering a box). At each check
    (every frame, and ``checks_per_frame - 1`` more times between frames, for brief windows)
    where ``ready(sim, next_frame)`` holds, a twin is forked and ``manipulate``d (it may return
    False to decline); the change is kept if none of ``hidden_ids`` shows in either simulation
    then. The manipulation frame is the first frame rendered after it; ``hidden_ids`` must be
    unseen there too, and both videos share its object states (see ``splice``). Returns
    (consistent, inconsistent, manipulation_frame); raises RejectedSample if no check succeeds
    or the change shows at the manipulation frame."""
    video = sim.video
    hidden = set(hidden_ids)
    shape = (video.num_frames, video.height, video.width)
    frames = [np.empty((*shape, 3), np.uint8), np.empty((*shape, 3), np.uint8)]
    masks = [np.empty(shape, np.uint8), np.empty(shape, np.uint8)]
    objects = [
        np.empty((video.num_frames, specs.OBJECT_SLOTS), specs.OBJECT_STATE_DTYPE) for _ in range(2)
    ]
    chunks = [len(c) for c in np.array_split(np.arange(video.steps_per_frame), checks_per_frame)]
    twin: Simulation | None = None
    manipulation_frame = -1

    def unseen(mask: np.ndarray) -> bool:
        return not visible_ids(mask) & hidden

    def try_change(next_frame: int, mask: np.ndarray | None) -> Simulation | None:
        """The manipulated twin, if the change can happen unseen now (``mask``: sim's view)."""
        if next_frame >= video.num_frames or not ready(sim, next_frame):
            return None
        if not unseen(sim.render()[1] if mask is None else mask):
            return None
        candidate = sim.fork()
        if manipulate(candidate) is False or not unseen(candidate.render()[1]):
            return None
        return candidate

    for t in range(video.num_frames):
        for branch in (sim, twin):
            if branch is not None and script is not None:
                script(branch, t)
        frames[0][t], masks[0][t], objects[0][t] = sim.render()
        if twin is None and t >= 1:
            twin = try_change(t, masks[0][t])
            manipulation_frame = t if twin is not None else -1
        if twin is None:
            frames[1][t], masks[1][t], objects[1][t] = frames[0][t], masks[0][t], objects[0][t]
        else:
            frames[1][t], masks[1][t], objects[1][t] = twin.render()
        if t == manipulation_frame and not (unseen(masks[0][t]) and unseen(masks[1][t])):
            raise RejectedSample("the hidden change shows at the manipulation frame")
        for index, steps in enumerate(chunks):
            sim.step(steps)
            if twin is not None:
                twin.step(steps)
            elif index < len(chunks) - 1:
                twin = try_change(t + 1, None)
                manipulation_frame = t + 1 if twin is not None else -1
    if twin is None:
        raise RejectedSample("no moment where the hidden change could happen unseen")
    objects[1][manipulation_frame] = objects[0][manipulation_frame]  # shared, as in ``splice``
    return (frames[0], masks[0], objects[0]), (frames[1], masks[1], objects[1]), manipulation_frame
