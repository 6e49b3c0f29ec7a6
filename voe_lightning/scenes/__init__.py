"""Procedural MuJoCo stimuli for the five concepts: training clips (examples and controls) and
consistent/inconsistent probe pairs. One module per concept holds all of its scene logic, each a
``ConceptScene`` (``SCENES``, through which ``generate_clip`` and ``generate_probe`` dispatch), on
a toolkit of one module per idea: ``camera`` (video options, camera poses and ranges,
projection), ``appearance`` (shapes, colours), ``rendering`` (the stage every scene is built on,
the renderer), ``builder`` (MjSpec scene builder), ``simulation``, ``recording`` (probe pairs
forked at the hidden change, and the records every concept makes of its videos), ``sampling``
(seeded draws), ``container`` (the open box of solidity and containment) and ``screen``
(unchangeableness's lowered screen)."""

from __future__ import annotations

from typing import Any, Protocol

from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes import (
    containment,
    continuity,
    object_persistence,
    solidity,
    unchangeableness,
)
from voe_lightning.scenes.camera import CameraRange, VideoOptions
from voe_lightning.specs import (
    CLIP_KINDS_BY_CONCEPT,
    CONCEPTS,
    GENERALIZATION_VARIANTS,
    PROBE_VARIANTS,
    STANDARD_VARIANTS,
)

__all__ = [
    "CONCEPTS",
    "CLIP_KINDS_BY_CONCEPT",
    "PROBE_VARIANTS",
    "STANDARD_VARIANTS",
    "GENERALIZATION_VARIANTS",
    "ConceptScene",
    "VideoOptions",
    "check_video",
    "concept_scene",
    "generate_clip",
    "generate_probe",
]


class ConceptScene(Protocol):
    """What a concept's scene module offers (docs/architecture.md §4): its camera distribution,
    the check of video options before anything renders, its training clips and probe pairs.
    Each module in ``SCENES`` is checked against it by mypy."""

    CAMERA: CameraRange

    def check_video(self, video: VideoOptions) -> None:
        """Raise a ValueError naming what would do if the scenes cannot render ``video``."""

    def clip(self, kind: str, seed: int, video: VideoOptions) -> TensorDict:
        """The training clip (example or control) of ``kind`` drawn at ``seed``."""

    def probe(self, variant: str, seed: int, video: VideoOptions) -> TensorDict:
        """The consistent/inconsistent probe pair of ``variant`` drawn at ``seed``."""


#: Each concept's scene module, by concept name (in ``specs.CONCEPTS`` order).
SCENES: dict[str, ConceptScene] = {
    "object_persistence": object_persistence,
    "unchangeableness": unchangeableness,
    "continuity": continuity,
    "solidity": solidity,
    "containment": containment,
}


def concept_scene(concept: str) -> ConceptScene:
    """The scene module of ``concept`` (a ValueError lists the valid concepts)."""
    specs.check_concept(concept)
    return SCENES[concept]


def check_video(concept: str, **options: Any) -> None:
    """Refuse video options (VideoOptions fields) that ``concept``'s scenes cannot render,
    before anything is rendered."""
    concept_scene(concept).check_video(VideoOptions(**options))


def generate_clip(concept: str, kind: str, seed: int, **options: Any) -> TensorDict:
    """Render one training clip (``kind`` is ``example`` or one of the concept's controls).
    ``options`` are VideoOptions fields (num_frames, height, width, duration, timestep)."""
    specs.check_kind(concept, kind)
    return concept_scene(concept).clip(kind, int(seed), VideoOptions(**options))


def generate_probe(concept: str, variant: str, seed: int, **options: Any) -> TensorDict:
    """Render one consistent/inconsistent probe pair of ``variant`` (see PROBE_VARIANTS)."""
    specs.check_variant(concept, variant)
    return concept_scene(concept).probe(variant, int(seed), VideoOptions(**options))
