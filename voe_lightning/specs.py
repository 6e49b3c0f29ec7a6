"""The data contract: names of concepts, clip kinds and probe variants, and the torchrl specs
of every record (docs/architecture.md §3). Generators, the store, DataModules and tests all use
these."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, get_args

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded

#: The five concepts of the paper (§3). A Literal so that configs naming another are refused
#: by LightningCLI before any work starts, with the valid names listed.
Concept = Literal["object_persistence", "unchangeableness", "continuity", "solidity", "containment"]
CONCEPTS: tuple[str, ...] = get_args(Concept)

#: Training clip kinds per concept: the consistent ``example`` and every control of the paper (§3).
CLIP_KINDS_BY_CONCEPT: dict[str, tuple[str, ...]] = {
    "object_persistence": ("example", "plank_beside_object", "plank_on_empty_floor"),
    "unchangeableness": ("example", "objects_only", "screen_only"),
    "continuity": ("example", "gap_block"),
    "solidity": ("example", "no_object", "object_behind_container"),
    "containment": ("example", "cube_behind_container", "cube_random_position"),
}

#: What an unchangeableness probe changes behind the screen (paper §3): one quadruplet each.
UNCHANGEABLENESS_CHANGES: tuple[str, ...] = ("position", "color", "shape")

#: The row name of a quadruplet's test (``statistics.quadruplet_test``) in a concept with one;
#: a concept with several (unchangeableness) names each ``<change>_quadruplet``.
QUADRUPLET = "quadruplet"
#: Per concept, each of its quadruplets (docs/architecture.md §4): its row name -> its two halves,
#: the probe variants whose pairs of one seed are (A, AB) and (B, BA) of one scene draw, so that
#: after the change each pair's inconsistent video is the other's consistent one, byte for byte.
#: A concept's verdict is the quadruplet test of each of its quadruplets.
#: The two halves of a concept with one quadruplet (and of a benchmark's quadruplets).
QUADRUPLET_VARIANTS: tuple[str, str] = ("standard", "counterbalanced")
QUADRUPLETS: dict[str, dict[str, tuple[str, str]]] = {
    "object_persistence": {QUADRUPLET: QUADRUPLET_VARIANTS},
    "unchangeableness": {
        f"{change}_{QUADRUPLET}": (change, f"{change}_counterbalanced")
        for change in UNCHANGEABLENESS_CHANGES
    },
    "continuity": {QUADRUPLET: QUADRUPLET_VARIANTS},
    "solidity": {QUADRUPLET: QUADRUPLET_VARIANTS},
    "containment": {QUADRUPLET: QUADRUPLET_VARIANTS},
}
#: Concepts whose verdict is read from quadruplets.
QUADRUPLET_CONCEPTS: tuple[str, ...] = tuple(QUADRUPLETS)
#: Every quadruplet row name, of any concept.
QUADRUPLET_ROWS: frozenset[str] = frozenset(row for rows in QUADRUPLETS.values() for row in rows)

#: The variants a concept's verdict reads: its quadruplets' halves, in order.
VERDICT_VARIANTS: dict[str, tuple[str, ...]] = {
    concept: tuple(variant for halves in quadruplets.values() for variant in halves)
    for concept, quadruplets in QUADRUPLETS.items()
}
#: Probe variants reported beside a concept's verdict and never read by it: the paper's
#: continuity probe, which no splice of two physical videos gives (docs/stimuli.md).
REPORTED_BESIDE_BY_CONCEPT: dict[str, tuple[str, ...]] = {"continuity": ("paper",)}
REPORTED_BESIDE: frozenset[str] = frozenset(
    variant for variants in REPORTED_BESIDE_BY_CONCEPT.values() for variant in variants
)
#: Probe variants per concept used for validation and test (paper §3; the counterbalanced
#: halves are ours, docs/architecture.md §4): the verdict's, then those reported beside it.
STANDARD_VARIANTS: dict[str, tuple[str, ...]] = {
    concept: VERDICT_VARIANTS[concept] + REPORTED_BESIDE_BY_CONCEPT.get(concept, ())
    for concept in CONCEPTS
}
#: Concepts whose VOE is read from the pooled test over ``standard`` + ``counterbalanced``
#: (the counterbalanced pair cancels every frame-local cue of the standard one).
POOLED_CONCEPTS: tuple[str, ...] = tuple(
    concept for concept, variants in STANDARD_VARIANTS.items() if "counterbalanced" in variants
)

#: Generalization probe variants (paper §5): a third pillar; one or two more objects than training.
GENERALIZATION_VARIANTS: dict[str, tuple[str, ...]] = {
    "object_persistence": (),
    "unchangeableness": tuple(
        f"{change}_plus{extra}" for change in UNCHANGEABLENESS_CHANGES for extra in (1, 2)
    ),
    "continuity": ("three_pillars",),
    "solidity": (),
    "containment": (),
}

#: Every generalization variant's name: no verdict reads them.
GENERALIZATION_VARIANT_NAMES: frozenset[str] = frozenset(
    variant for variants in GENERALIZATION_VARIANTS.values() for variant in variants
)

PROBE_VARIANTS: dict[str, tuple[str, ...]] = {
    concept: STANDARD_VARIANTS[concept] + GENERALIZATION_VARIANTS[concept] for concept in CONCEPTS
}

#: Flat, ordered vocabularies: records store the index into these (``Categorical`` specs).
CLIP_KINDS: tuple[str, ...] = tuple(
    dict.fromkeys(kind for kinds in CLIP_KINDS_BY_CONCEPT.values() for kind in kinds)
)
VARIANTS: tuple[str, ...] = tuple(
    dict.fromkeys(variant for variants in PROBE_VARIANTS.values() for variant in variants)
)

#: Default video geometry (paper: 15 frames of 64x64 RGB, about 3 s of simulated time).
NUM_FRAMES = 15
HEIGHT = 64
WIDTH = 64
#: Largest number of distinct object ids a mask may carry (0 is the background).
MAX_OBJECT_ID = 32
#: Object-state slots per frame, indexed by mask id (slot 0, the background, stays empty).
OBJECT_SLOTS = MAX_OBJECT_ID + 1
#: What ``objects/shape_label`` indexes (Kubric's name; Composite reserves ``shape``): ``none``
#: marks a slot with no object; an object made of several primitives (a container) is
#: ``compound``.
OBJECT_SHAPES: tuple[str, ...] = (
    "none",
    "sphere",
    "box",
    "cylinder",
    "capsule",
    "ellipsoid",
    "compound",
)


def _check_name(kind: str, name: str, valid: tuple[str, ...]) -> None:
    if name not in valid:
        raise ValueError(f"unknown {kind} {name!r}; valid {kind}s are: {', '.join(valid)}")


def check_concept(concept: str) -> None:
    """Raise a ValueError listing the valid concepts if ``concept`` is not one of them."""
    _check_name("concept", concept, CONCEPTS)


def check_kind(concept: str, kind: str) -> None:
    """Raise a ValueError listing the valid clip kinds of ``concept``."""
    check_concept(concept)
    _check_name(f"clip kind for {concept}", kind, CLIP_KINDS_BY_CONCEPT[concept])


def check_variant(concept: str, variant: str) -> None:
    """Raise a ValueError listing the valid probe variants of ``concept``."""
    check_concept(concept)
    _check_name(f"probe variant for {concept}", variant, PROBE_VARIANTS[concept])


def quadruplet_half(concept: str, variant: str) -> tuple[str, int]:
    """(row name, 0 or 1) of the quadruplet whose first or second half ``variant`` is; a
    ValueError listing ``concept``'s halves if it is none."""
    for row, halves in QUADRUPLETS.get(concept, {}).items():
        if variant in halves:
            return row, halves.index(variant)
    valid = [v for halves in QUADRUPLETS.get(concept, {}).values() for v in halves]
    raise ValueError(
        f"{variant!r} is no half of a {concept} quadruplet; valid halves are: "
        f"{', '.join(valid) or 'none'}"
    )


def _video_spec(
    num_frames: int, height: int, width: int, objects: bool
) -> dict[str, Bounded | Composite]:
    video = {
        "frames": Bounded(0, 255, shape=(num_frames, height, width, 3), dtype=torch.uint8),
        "mask": Bounded(0, MAX_OBJECT_ID, shape=(num_frames, height, width), dtype=torch.uint8),
    }
    if not objects:
        return video
    return {**video, "depth": depth_spec(num_frames), "objects": objects_spec(num_frames)}


#: What the depth image shows of each mask id at a frame (``scenes.depth.depth_measures``).
DEPTH_MEASURES = ("mean", "near", "cut")


def depth_spec(num_frames: int = NUM_FRAMES) -> Unbounded:
    """Per frame and mask id [T, OBJECT_SLOTS, 3], what a depth camera shows of it, measured
    over its visible pixels alone (``DEPTH_MEASURES``): their mean and least depth along the
    view axis (m) and the share of its outline where the frame ends or another object is nearer
    (in front); zeros where the id is not seen. Camera-recoverable, unlike ``objects``: a
    function of that frame's depth image and mask. The generator's records carry it (stimuli
    version 13 on); a benchmark's do not. The depth image itself ([T, H, W], DESIGN.md) is not
    stored yet: these measures are made from it at render time, in float."""
    return Unbounded(shape=(num_frames, OBJECT_SLOTS, len(DEPTH_MEASURES)), dtype=torch.float32)


def objects_spec(num_frames: int = NUM_FRAMES) -> Composite:
    """Per-frame states of a video's objects, what a perfect 3D perception would recover (as
    Kubric and Physion export), indexed [T, OBJECT_SLOTS] by mask id: world ``position`` (m) and
    ``orientation`` (quaternion w, x, y, z) of the object, ``size`` (half-extents of its
    bounding box in its body frame, m), ``shape_label`` (index into OBJECT_SHAPES; 0: no object
    with this id at that frame), ``color`` (RGB in [0, 1]) and ``visible_fraction`` (the share of
    the frame's pixels that show it: 0 when hidden). ``position`` is the centre of that bounding
    box: the body's origin for a one-primitive object; a container, whose body origin lies on
    its floor, has it half its height up. Ground truth for every object in the scene, hidden or
    not: a model that may only see what is visible must mask out the states of hidden objects
    itself. An object taken out of the scene (parked out of view) has no states at that frame.
    An id names one spatio-temporal object, as a tracker would: a body swapped in for another
    while hidden holds that one's id, and the states are the current holder's. A probe pair
    shares the states of its manipulation frame (see ``scenes.recording.splice``)."""
    slots = (num_frames, OBJECT_SLOTS)
    return Composite(
        position=Unbounded(shape=(*slots, 3), dtype=torch.float32),
        orientation=Bounded(-1.0, 1.0, shape=(*slots, 4), dtype=torch.float32),
        size=Unbounded(shape=(*slots, 3), dtype=torch.float32),
        shape_label=Categorical(len(OBJECT_SHAPES), shape=slots, dtype=torch.int64),
        color=Bounded(0.0, 1.0, shape=(*slots, 3), dtype=torch.float32),
        visible_fraction=Bounded(0.0, 1.0, shape=slots, dtype=torch.float32),
    )


#: One object slot of ``objects_spec`` and of ``depth_spec`` (field ``depth``) as a numpy
#: structured dtype: generators collect a video's states in an array [T, OBJECT_SLOTS] of it,
#: which ``clip_record``/``probe_record`` store as the record's ``objects`` and ``depth``.
OBJECT_STATE_DTYPE = np.dtype(
    [
        (name, torch.empty((), dtype=leaf.dtype).numpy().dtype, tuple(leaf.shape[2:]))
        for name, leaf in objects_spec(1).items()
    ]
    + [("depth", np.float32, (len(DEPTH_MEASURES),))]
)


def _camera_spec(num_frames: int) -> Unbounded:
    """Per-frame camera pose: lookat x, y, z, distance, azimuth (deg), elevation (deg)."""
    return Unbounded(shape=(num_frames, 6), dtype=torch.float32)


def clip_spec(
    num_frames: int = NUM_FRAMES, height: int = HEIGHT, width: int = WIDTH, objects: bool = True
) -> Composite:
    """Spec of a training clip (an example or a control); with ``objects`` (the generator's
    records) it carries the per-frame object states of ``objects_spec``, which external
    benchmarks' records lack."""
    return Composite(
        **_video_spec(num_frames, height, width, objects),
        camera=_camera_spec(num_frames),
        concept=Categorical(len(CONCEPTS), shape=(), dtype=torch.int64),
        kind=Categorical(len(CLIP_KINDS), shape=(), dtype=torch.int64),
        seed=Unbounded(shape=(), dtype=torch.int64),
    )


def probe_spec(
    num_frames: int = NUM_FRAMES, height: int = HEIGHT, width: int = WIDTH, objects: bool = True
) -> Composite:
    """Spec of a probe pair: a consistent and an inconsistent video that differ only after
    ``manipulation_frame``; ``manipulated_ids`` holds the mask ids the hidden change touched
    (padded with 0). Each video carries its object states when ``objects`` (as in
    ``clip_spec``)."""
    return Composite(
        consistent=Composite(**_video_spec(num_frames, height, width, objects)),
        inconsistent=Composite(**_video_spec(num_frames, height, width, objects)),
        camera=_camera_spec(num_frames),
        concept=Categorical(len(CONCEPTS), shape=(), dtype=torch.int64),
        variant=Categorical(len(VARIANTS), shape=(), dtype=torch.int64),
        manipulation_frame=Bounded(0, num_frames - 1, shape=(), dtype=torch.int64),
        manipulated_ids=Bounded(0, MAX_OBJECT_ID, shape=(4,), dtype=torch.int64),
        seed=Unbounded(shape=(), dtype=torch.int64),
    )


def _video(
    frames: np.ndarray, mask: np.ndarray, objects: np.ndarray | None = None
) -> dict[str, torch.Tensor | TensorDictBase]:
    """A video's record entries; ``objects`` [T, OBJECT_SLOTS] of OBJECT_STATE_DTYPE, if given,
    becomes the nested ``objects`` TensorDict and the video's ``depth``."""
    video = {
        "frames": torch.from_numpy(np.ascontiguousarray(frames)),
        "mask": torch.from_numpy(np.ascontiguousarray(mask)),
    }
    if objects is None:
        return video
    if objects.dtype != OBJECT_STATE_DTYPE or objects.shape != (len(frames), OBJECT_SLOTS):
        raise ValueError(
            f"object states must be [{len(frames)}, {OBJECT_SLOTS}] of OBJECT_STATE_DTYPE, got "
            f"{list(objects.shape)} of {objects.dtype}"
        )
    states = {
        name: torch.from_numpy(np.ascontiguousarray(objects[name]))
        for name in objects_spec(1).keys()
    }
    depth = torch.from_numpy(np.ascontiguousarray(objects["depth"]))
    return {**video, "depth": depth, "objects": TensorDict(states, batch_size=[])}


def _camera(camera: np.ndarray, num_frames: int) -> torch.Tensor:
    """Poses [T, 6] float32 from per-frame poses [T, 6] or one pose [6] for every frame."""
    return torch.from_numpy(np.array(np.broadcast_to(camera, (num_frames, 6)), dtype=np.float32))


def clip_record(
    frames: np.ndarray,
    mask: np.ndarray,
    camera: np.ndarray,
    concept: int,
    kind: int,
    seed: int,
    objects: np.ndarray | None = None,
) -> TensorDict:
    """A clip record (``clip_spec`` keys) from uint8 frames [T, H, W, 3] and mask [T, H, W],
    camera poses [T, 6] (or one [6] for all frames), vocabulary indices (ours, or a
    benchmark's own) and the object states [T, OBJECT_SLOTS] of OBJECT_STATE_DTYPE (None for
    a benchmark's video, which has none: ``clip_spec(objects=False)``)."""
    return TensorDict(
        {
            **_video(frames, mask, objects),
            "camera": _camera(camera, len(frames)),
            "concept": torch.tensor(concept, dtype=torch.int64),
            "kind": torch.tensor(kind, dtype=torch.int64),
            "seed": torch.tensor(seed, dtype=torch.int64),
        },
        batch_size=[],
    )


def probe_record(
    consistent: tuple[np.ndarray, ...],
    inconsistent: tuple[np.ndarray, ...],
    camera: np.ndarray,
    concept: int,
    variant: int,
    manipulation_frame: int,
    seed: int,
    manipulated_ids: Sequence[int] = (),
) -> TensorDict:
    """A probe record (``probe_spec`` keys) from the (frames, mask, objects) of its consistent
    and inconsistent video (objects as in ``clip_record``, or (frames, mask) for a benchmark's
    videos), camera as in ``clip_record`` and vocabulary indices;
    ``manipulated_ids`` (at most 4) are padded with 0, which also stands for unknown."""
    ids = [int(i) for i in manipulated_ids]
    if len(ids) > 4:
        raise ValueError(f"a probe names at most 4 manipulated ids, got {ids}")
    return TensorDict(
        {
            "consistent": _video(*consistent),
            "inconsistent": _video(*inconsistent),
            "camera": _camera(camera, len(consistent[0])),
            "concept": torch.tensor(concept, dtype=torch.int64),
            "variant": torch.tensor(variant, dtype=torch.int64),
            "manipulation_frame": torch.tensor(manipulation_frame, dtype=torch.int64),
            "manipulated_ids": torch.tensor(ids + [0] * (4 - len(ids)), dtype=torch.int64),
            "seed": torch.tensor(seed, dtype=torch.int64),
        },
        batch_size=[],
    )


def to_model_input(frames: torch.Tensor) -> torch.Tensor:
    """The one conversion from stored frames to model input: uint8 [..., T, H, W, 3] ->
    float [..., T, 3, H, W] in [0, 1]."""
    if frames.dtype != torch.uint8:
        raise TypeError(f"frames must be uint8 as stored, got {frames.dtype}")
    return frames.movedim(-1, -3).float().div_(255.0)


def concept_name(record: TensorDictBase) -> str:
    """The concept name of a single (unbatched) record."""
    return CONCEPTS[int(record["concept"])]


def variant_name(record: TensorDictBase) -> str:
    """The variant name of a single (unbatched) probe record."""
    return VARIANTS[int(record["variant"])]
