"""Rendering: the stage every scene is built on (render settings, floor, light and the floor
textures all scenes share) and the per-process Renderer that draws any scene on it with one GL
context, one MjrContext and one MjvScene, giving RGB frames and the geom seen at each pixel
(from which ``Simulation`` makes object-id masks)."""

from __future__ import annotations

import functools
import importlib
import os

import mujoco
import numpy as np

from voe_lightning.scenes.camera import CameraPose, VideoOptions

#: Floor textures shared by every model, so one GPU context serves all scenes (see Renderer).
_FLOOR_TEXTURES = ("checker", "gradient", "flat")


def stage(
    rng: np.random.Generator, video: VideoOptions, floor_pattern: str | None = None
) -> mujoco.MjSpec:
    """A new scene's MjSpec before any object: render settings, the shared floor textures, a
    floor of a random pattern, tint and repeat (drawn from ``rng``) and the light. Every scene
    starts here, so one Renderer made from one stage draws them all."""
    spec = mujoco.MjSpec()
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
    return spec


class Renderer:
    """Renders RGB frames and geom-id images for any model built on ``stage``, reusing one
    GL context, one MjrContext and one MjvScene (a new mujoco.Renderer costs ~70-100 ms).
    Valid because every such model carries the same textures and only primitive geoms."""

    def __init__(self, height: int, width: int):
        template = stage(
            np.random.default_rng(0), VideoOptions(height=height, width=width)
        ).compile()
        self.height, self.width = height, width
        # Choose the backend from MUJOCO_GL now, not from whatever it was when mujoco was imported.
        backend = os.environ.get("MUJOCO_GL", "egl")
        gl_context_class = importlib.import_module(f"mujoco.{backend}").GLContext
        _check_frame_size(height, width, gl_context_class)
        self._gl_context = gl_context_class(max(width, 64), max(height, 64))
        self._gl_context.make_current()
        try:
            self._context = mujoco.MjrContext(template, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        except mujoco.FatalError as error:  # the size passed the check: name it all the same
            raise ValueError(
                f"the renderer ({backend}) cannot draw frames of {height} x {width} "
                f"(height x width): {error}; use a smaller height and width"
            ) from error
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._context)
        self._scene = mujoco.MjvScene(template, maxgeom=500)
        self._option = mujoco.MjvOption()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._rect = mujoco.MjrRect(0, 0, width, height)
        self._rgb = np.empty((height, width, 3), np.uint8)
        self._depth = np.empty((height, width), np.float32)

    def render(
        self, model: mujoco.MjModel, data: mujoco.MjData, camera: CameraPose
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """RGB uint8 [H, W, 3], the id of the geom seen at each pixel (-1: none) [H, W] and
        each pixel's depth along the view axis (m, float32 [H, W]), read with the RGB."""
        self._gl_context.make_current()
        self._camera.lookat[:] = camera.lookat
        self._camera.distance = camera.distance
        self._camera.azimuth = camera.azimuth
        self._camera.elevation = camera.elevation
        mujoco.mjv_updateScene(
            model, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene
        )
        mujoco.mjr_render(self._rect, self._scene, self._context)
        mujoco.mjr_readPixels(self._rgb, self._depth, self._rect, self._context)
        rgb = np.flipud(self._rgb).copy()
        depth = metres(np.flipud(self._depth), model)

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
        return rgb, lookup[np.clip(segid, 0, self._scene.ngeom)], depth


def metres(buffer: np.ndarray, model: mujoco.MjModel) -> np.ndarray:
    """Depth along the view axis (m, float32) from OpenGL's depth buffer in [0, 1], between the
    near and far clipping planes MuJoCo sets from ``model``'s extent."""
    extent = float(model.stat.extent)
    near, far = float(model.vis.map.znear) * extent, float(model.vis.map.zfar) * extent
    metres: np.ndarray = near / (1.0 - buffer.astype(np.float64) * (1.0 - near / far))
    return metres.astype(np.float32)


def _check_frame_size(height: int, width: int, gl_context_class: type) -> None:
    """Refuse a frame larger than the GL renderbuffers may be (GL_MAX_RENDERBUFFER_SIZE a
    side), naming the size and the limit, before a context of that size is made (seconds of
    allocation) and MuJoCo says "Offscreen framebuffer is not complete"."""
    if max(height, width) <= MIN_RENDERBUFFER_SIZE:
        return  # every OpenGL 3 renderer draws this size: no context to query
    limit = _renderbuffer_limit(gl_context_class)
    if limit is not None and max(height, width) > limit:
        raise ValueError(
            f"frames of {height} x {width} (height x width) are larger than this renderer "
            f"draws: at most {limit} pixels a side (GL_MAX_RENDERBUFFER_SIZE); use a height "
            f"and width of at most {limit}"
        )


#: The GL_MAX_RENDERBUFFER_SIZE every OpenGL 3 implementation reaches at least.
MIN_RENDERBUFFER_SIZE = 1024


@functools.cache
def _renderbuffer_limit(gl_context_class: type) -> int | None:
    """The largest renderbuffer side of a small context of ``gl_context_class``, queried once
    per process (None: it cannot be queried; MjrContext then says what fails)."""
    try:
        from OpenGL import GL

        context = gl_context_class(64, 64)
        try:
            context.make_current()
            return int(GL.glGetIntegerv(GL.GL_MAX_RENDERBUFFER_SIZE))
        finally:
            context.free()
    except Exception:  # no PyOpenGL, or no context of that kind here
        return None


_RENDERERS: dict[tuple[int, int, int], Renderer] = {}


def get_renderer(height: int, width: int) -> Renderer:
    """The renderer of this process for this frame size (made once per worker process)."""
    key = (os.getpid(), height, width)
    if key not in _RENDERERS:
        _RENDERERS[key] = Renderer(height, width)
    return _RENDERERS[key]
