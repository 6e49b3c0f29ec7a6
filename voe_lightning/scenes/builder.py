"""Building a scene: ``SceneBuilder`` adds named objects made of primitive ``Geom``s to a stage
(floor, light, camera) with MjSpec, gives each the mask id a tracker would give it, and
compiles the whole into a ``Simulation``."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from voe_lightning import specs
from voe_lightning.scenes.appearance import SHAPES, rgba
from voe_lightning.scenes.camera import CameraPose, VideoOptions
from voe_lightning.scenes.rendering import stage
from voe_lightning.scenes.simulation import SceneObject, Simulation


@dataclass
class Geom:
    """One primitive of an object, placed relative to its body."""

    shape: str
    size: Sequence[float]
    pos: Sequence[float] = (0.0, 0.0, 0.0)
    quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)


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
        self.spec = stage(rng, video, floor_pattern)

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
        self,
        name: str,
        shape: str,
        size: Sequence[float],
        pos: Sequence[float],
        color: str | Sequence[float],
        **kwargs: Any,
    ) -> SceneObject:
        """Add an object of one primitive geom."""
        return self.add(name, [Geom(shape, size)], pos, color, **kwargs)

    def build(self) -> Simulation:
        """Compile the scene into a simulation at time 0."""
        model = self.spec.compile()
        return Simulation(model, self.objects, self.video, self.camera)
