"""Procedural MuJoCo stimuli for the five concepts: training clips (examples and controls) and
consistent/inconsistent probe pairs. One module per concept holds all of its scene logic, on a
toolkit of one module per idea: ``camera`` (video options, camera poses and ranges, projection),
``appearance`` (shapes, colours), ``rendering`` (the stage every scene is built on, the
renderer), ``builder`` (MjSpec scene builder), ``simulation``, ``recording`` (probe pairs forked
at the hidden change), ``sampling`` (seeded draws), ``container`` (the open box of solidity and
containment) and ``screen`` (unchangeableness's lowered screen)."""

from __future__ import annotations

import importlib

from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes.camera import VideoOptions
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
    "VideoOptions",
    "generate_clip",
    "generate_probe",
]


def _module(concept: str):
    specs.check_concept(concept)
    return importlib.import_module(f"voe_lightning.scenes.{concept}")


def check_video(concept: str, **options) -> None:
    """Refuse video options (VideoOptions fields) that ``concept``'s scenes cannot render,
    before anything is rendered; a concept without such limits accepts any."""
    check = getattr(_module(concept), "check_video", None)
    if check is not None:
        check(VideoOptions(**options))


def generate_clip(concept: str, kind: str, seed: int, **options) -> TensorDict:
    """Render one training clip (``kind`` is ``example`` or one of the concept's controls).
    ``options`` are VideoOptions fields (num_frames, height, width, duration, timestep)."""
    specs.check_kind(concept, kind)
    return _module(concept).clip(kind, int(seed), VideoOptions(**options))


def generate_probe(concept: str, variant: str, seed: int, **options) -> TensorDict:
    """Render one consistent/inconsistent probe pair of ``variant`` (see PROBE_VARIANTS)."""
    specs.check_variant(concept, variant)
    return _module(concept).probe(variant, int(seed), VideoOptions(**options))
