"""Recording videos from a simulation, and the records every concept makes of them: for probes,
the consistent video and its inconsistent twin, forked from one simulation at the hidden
manipulation and identical through the manipulation frame (docs/architecture.md §4), either at
a chosen frame (``record_pair``) or as soon as the physics allows the change unseen
(``record_pair_when``); a whole video with the state at every frame (``record_tracking``), to
fork later at a frame an object's path chooses; a quadruplet's two pairs spliced from two
consistent videos of one scene (``quadruplet``, with ``record_with_ghost`` for a second history
of one motion); and a training clip's record, drawn until valid (``draw_clip``), and a probe
pair's (``pair_record``, ``quadruplet_record``)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes.camera import CameraPose
from voe_lightning.scenes.sampling import RejectedSample, draw_until_valid, rng_for
from voe_lightning.scenes.simulation import Simulation, visible_ids

#: A rendered video: uint8 frames [T, H, W, 3], masks [T, H, W] and object states [T, OBJECT_SLOTS]
#: of ``specs.OBJECT_STATE_DTYPE``, as ``Simulation.record`` gives them.
Video = tuple[np.ndarray, np.ndarray, np.ndarray]
#: A quadruplet as each concept's cached ``quadruplet`` gives it: its pairs ((A, AB), (B, BA)),
#: the camera pose array, the manipulation frame and the manipulated id (or ids).
Quadruplet = tuple[
    tuple[tuple[Video, Video], tuple[Video, Video]], np.ndarray, int, int | tuple[int, ...]
]


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


def join(prefix: Video, rest: Video) -> Video:
    """One video from two consecutive parts (frames, masks and object states each)."""
    frames, masks, objects = (np.concatenate([a, b]) for a, b in zip(prefix, rest))
    return frames, masks, objects


def head(video: Video, stop: int) -> Video:
    """The part of ``video`` before frame ``stop`` (frames, masks and object states)."""
    frames, masks, objects = video
    return frames[:stop], masks[:stop], objects[:stop]


def tail(video: Video, start: int) -> Video:
    """The part of ``video`` from frame ``start`` on (frames, masks and object states)."""
    frames, masks, objects = video
    return frames[start:], masks[start:], objects[start:]


def quadruplet(
    first: Video, second: Video, manipulation_frame: int
) -> tuple[tuple[Video, Video], tuple[Video, Video]]:
    """The two probe pairs of one scene draw (docs/architecture.md §4, "Quadruplets"): (A, AB)
    and (B, BA) from consistent videos A = ``first`` and B = ``second``, where AB is A through
    the manipulation frame m and B after it, BA the reverse. So after m the inconsistent video
    of each pair is byte-identical to the consistent video of the other. A and B must render
    alike at m (frames and masks; the change is hidden there), else RejectedSample."""
    m = manipulation_frame
    if not all(np.array_equal(a[m], b[m]) for a, b in zip(first[:2], second[:2])):
        raise RejectedSample(f"the two consistent videos differ at the manipulation frame {m}")
    return (first, splice(first, tail(second, m), m)), (second, splice(second, tail(first, m), m))


def quadruplet_record(concept: str, variant: str, seed: int, drawn: Quadruplet) -> TensorDict:
    """The probe record of ``variant``'s half of a quadruplet ``drawn`` = (((A, AB), (B, BA)),
    camera, manipulation frame, manipulated id or ids), as a concept's cached ``quadruplet``
    gives it: the first half of ``specs.QUADRUPLETS`` (``standard``, or an unchangeableness
    change) is (A, AB), the second (``counterbalanced``, ``<change>_counterbalanced``) is
    (B, BA); its arrays are copies, so the cache stays as it was."""
    pairs, camera, frame, manipulated = drawn
    _, half = specs.quadruplet_half(concept, variant)
    consistent, inconsistent = (_copy(video) for video in pairs[half])
    return pair_record(
        concept,
        variant,
        seed,
        (consistent, inconsistent),
        camera,
        frame,
        np.atleast_1d(manipulated).tolist(),
    )


def _copy(video: Video) -> Video:
    """A copy of ``video``'s arrays (frames, masks and object states)."""
    frames, masks, objects = video
    return np.copy(frames), np.copy(masks), np.copy(objects)


def pair_record(
    concept: str,
    variant: str,
    seed: int,
    pair: tuple[Video, Video],
    camera: np.ndarray,
    manipulation_frame: int,
    manipulated_ids: Sequence[int],
) -> TensorDict:
    """The probe record of ``concept``'s ``variant`` at ``seed`` from its (consistent,
    inconsistent) videos, the camera pose array, the manipulation frame and the ids the hidden
    change touches: the one place a concept's names become the record's vocabulary indices."""
    consistent, inconsistent = pair
    return specs.probe_record(
        consistent,
        inconsistent,
        camera,
        specs.CONCEPTS.index(concept),
        specs.VARIANTS.index(variant),
        manipulation_frame,
        seed,
        manipulated_ids,
    )


def draw_clip(
    concept: str,
    kind: str,
    seed: int,
    draw: Callable[[np.random.Generator], tuple[CameraPose, Video]],
) -> TensorDict:
    """The record of ``concept``'s training clip of ``kind`` at ``seed``, as every concept makes
    its clips: ``draw`` (the camera and the recorded video of one scene draw, or a
    RejectedSample) is called with the generator of (seed, concept, kind) until a draw holds."""
    specs.check_kind(concept, kind)

    def make(rng: np.random.Generator) -> TensorDict:
        camera, (frames, masks, objects) = draw(rng)
        return specs.clip_record(
            frames,
            masks,
            camera.as_array(),
            specs.CONCEPTS.index(concept),
            specs.CLIP_KINDS.index(kind),
            seed,
            objects,
        )

    return draw_until_valid(make, rng_for(seed, concept, kind))


def record_with_ghost(
    sim: Simulation, num_frames: int, change: Callable[[Simulation], None]
) -> tuple[Video, Video]:
    """Render ``num_frames`` frames of ``sim`` and, at each, of a copy of it altered by
    ``change`` (e.g. an object removed): the same motion seen in two scenes, for a quadruplet's
    second history where the change touches nothing else before the manipulation frame."""
    seen: list[Video] = []
    altered: list[Video] = []
    for _ in range(num_frames):
        ghost = sim.fork()
        change(ghost)
        seen.append(sim.render())
        altered.append(ghost.render())
        sim.step(sim.video.steps_per_frame)
    return _stacked(seen), _stacked(altered)


def _stacked(renders: list[Video]) -> Video:
    """One video from the renders of its frames, one (frame, mask, object states) each."""
    frames, masks, objects = (np.stack(part) for part in zip(*renders))
    return frames, masks, objects


def record_tracking(sim: Simulation, name: str) -> tuple[Video, list[np.ndarray], np.ndarray]:
    """Render the whole video, keeping the simulation state and the position of object ``name``
    at every frame (to fork a twin later at a frame the object's path chooses)."""
    states: list[np.ndarray] = []
    positions: list[np.ndarray] = []

    def keep(sim: Simulation, frame: int) -> None:
        states.append(sim.get_state())
        positions.append(sim.position(name))

    video = sim.record(sim.video.num_frames, keep)
    return video, states, np.array(positions)


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
        raise ValueError(
            f"manipulation_frame must be in [1, {total - 1}], got {manipulation_frame}"
        )
    prefix = sim.record(manipulation_frame, script)
    twin = sim.fork()
    manipulate(twin)
    rest = total - manipulation_frame
    consistent_rest = sim.record(rest, script, first_frame=manipulation_frame)
    inconsistent_rest = twin.record(
        rest, script_inconsistent or script, first_frame=manipulation_frame
    )
    consistent = join(prefix, consistent_rest)
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
