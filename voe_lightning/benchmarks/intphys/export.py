"""A probe split in IntPhys' released layout (Riochet et al. 2018), as its labelled dev set
is: per concept a benchmark root ``<concept>/dev/<block>/<scene>/<movie>/`` holding
``scene/scene_001.png ...`` (the frames, lossless), ``masks/masks_001.png ...`` (our object
ids, 0 the background) and ``status.json`` whose ``header.is_possible`` is the label, so
``voe_lightning.benchmarks.intphys.reader`` and IntPhys harnesses read it.

A scene is a quadruplet: movies 1 and 2 are its consistent videos A and B, 3 and 4 the
inconsistent AB and BA, so the scene's first possible movie pairs with its first impossible
one as our first half does (the reader pairs them by shared prefix, and finds these). IntPhys
has three blocks and we have five concepts, so each concept has a root of its own and the
block nearest to what its viewer sees (``BLOCKS``); scenes are numbered across the concepts,
so the roots merge into one ``dev/`` tree (two concepts share a block) with no scene written
twice. A lone pair (no quadruplet) has no place in an IntPhys scene and is left out, listed in
the manifest."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
from PIL import Image
from tensordict import TensorDictBase

from voe_lightning.benchmarks.intphys import reader
from voe_lightning.export.manifest import ExportFolder, Progress, Written, group_entry
from voe_lightning.export.probes import ROLES, ProbeGroup, ProbePair, ProbeSource

#: The IntPhys block each concept is written as, by what its inconsistent video shows: an
#: object gone (object persistence; solidity, whose block falls through the floor), changed
#: (unchangeableness), or where its path cannot have taken it (continuity; containment, whose
#: cube stays behind when its container is moved).
BLOCKS: dict[str, str] = {
    "object_persistence": "O1",
    "unchangeableness": "O2",
    "continuity": "O3",
    "solidity": "O1",
    "containment": "O3",
}
#: The labelled IntPhys split the export imitates.
SPLIT = "dev"
#: PNG compression level (zlib's 0-9): fixed, so one store gives byte-identical frames.
PNG_LEVEL = 6
LONE_PAIR_REASON = (
    "an IntPhys scene is a quadruplet (2 possible + 2 impossible movies); a lone pair has no "
    "place in one (export as intphys2 or webdataset to keep it)"
)


def png_bytes(image: np.ndarray) -> bytes:
    """``image`` (uint8 [H, W, 3] RGB or [H, W] grey) as PNG bytes, losslessly."""
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(
        buffer, format="PNG", compress_level=PNG_LEVEL
    )
    return buffer.getvalue()


def movie_name(pair: ProbePair, role: str) -> str:
    """The movie folder (``1`` to ``4``) of a quadruplet video: A, B, AB, BA."""
    assert pair.half is not None
    return reader.MOVIES[2 * ROLES.index(role) + pair.half]


def scene_concepts(source: ProbeSource) -> tuple[list[str], int]:
    """The concepts with quadruplets, in order, and the digits of the scene folders, numbered
    across them: 4, as IntPhys', or more, so that they sort in order."""
    concepts = [group.concept for group in source.groups if group.quadruplet is not None]
    return list(dict.fromkeys(concepts)), max(4, len(str(len(concepts))))


def status(pair: ProbePair, role: str, block: str, manipulation_frame: int) -> bytes:
    """A movie's status.json: IntPhys' header with the label, and what the movie is."""
    document = {
        "header": {"block_name": block, "block_type": "test", "is_possible": role == ROLES[0]},
        "voe_lightning": {
            "concept": pair.concept,
            "variant": pair.variant,
            "seed": pair.seed,
            "quadruplet": pair.quadruplet,
            "video": pair.video_name(role),
            "role": role,
            "manipulation_frame": manipulation_frame,
            "masks": "masks/masks_NNN.png: object ids, 0 the background",
        },
    }
    return (json.dumps(document, indent=2) + "\n").encode()


def write_movie(
    folder: ExportFolder,
    movie: str,
    frames: np.ndarray,
    masks: np.ndarray,
    status_json: bytes,
) -> None:
    """One movie folder: its frames, masks and status.json."""
    for number, (frame, mask) in enumerate(zip(frames, masks), start=1):
        folder.write(reader.frame_file(Path(movie), number).as_posix(), png_bytes(frame))
        folder.write(f"{movie}/masks/masks_{number:03d}.png", png_bytes(mask))
    folder.write(f"{movie}/status.json", status_json)


def write_quadruplet(
    folder: ExportFolder, group: ProbeGroup, records: list[TensorDictBase], scene: str
) -> list[list[str]]:
    """A quadruplet's four movie folders under ``scene``; returns each pair's movies."""
    block = BLOCKS[group.concept]
    locations = []
    for pair, record in zip(group.pairs, records):
        movies = [f"{scene}/{movie_name(pair, role)}" for role in ROLES]
        for role, movie in zip(ROLES, movies):
            status_json = status(pair, role, block, int(record["manipulation_frame"]))
            video = record[role]
            write_movie(folder, movie, video["frames"].numpy(), video["mask"].numpy(), status_json)
        locations.append(movies)
    return locations


def left_out(group: ProbeGroup) -> dict[str, object]:
    """The manifest's note of a lone pair the layout has no place for."""
    pair = group.pairs[0]
    return {"concept": pair.concept, "variant": pair.variant, "seed": pair.seed} | {
        "reason": LONE_PAIR_REASON
    }


def write_intphys(source: ProbeSource, folder: ExportFolder, bar: Progress) -> Written:
    """Write ``source``'s quadruplets in IntPhys' dev layout, one root per concept (a
    ValueError when it holds none); its lone pairs are left out, and listed."""
    concepts, width = scene_concepts(source)
    if not concepts:
        raise ValueError(
            f"the {source.split} split of {source.root} holds no quadruplets for "
            f"{', '.join(source.concepts)}, and an IntPhys scene is one; export it as intphys2 "
            "or webdataset"
        )
    written = Written(
        layout={
            "split_folder": SPLIT,
            "concepts": {c: {"root": c, "block": BLOCKS[c]} for c in concepts},
            "movies": {"1": "A", "2": "B", "3": "AB", "4": "BA"},
            "video_location": "<concept>/dev/<block>/<scene>/<movie>: scene/scene_NNN.png, "
            "masks/masks_NNN.png, status.json",
        },
        encoding={
            "frames": "PNG, 8-bit RGB, lossless",
            "masks": "PNG, 8-bit grey: object ids, 0 the background",
            "labels": "status.json header.is_possible (consistent: true)",
        },
    )
    number = 0
    for group in source.groups:
        if group.quadruplet is None:
            written.left_out.append(left_out(group))
        else:
            number += 1
            scene = f"{group.concept}/{SPLIT}/{BLOCKS[group.concept]}/{number:0{width}d}"
            records = source.records(group)
            locations = write_quadruplet(folder, group, records, scene)
            written.groups.append(group_entry(group, records, locations, scene))
        bar.update(2 * len(group.pairs))
    return written
