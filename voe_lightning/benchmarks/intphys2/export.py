"""A probe split in IntPhys 2's released layout (Bordes et al. 2025): per concept a benchmark
root ``<concept>/Main/`` holding ``Videos/<name>.mp4``, one per video, and ``metadata.csv``
with IntPhys 2's columns, so ``voe_lightning.benchmarks.intphys2.reader`` and IntPhys 2 harnesses read
it. A quadruplet is a scene (``SceneIndex``): its first half's pair is ``type`` 1_Possible /
1_Impossible (A, AB), its second's 2_Possible / 2_Impossible (B, BA); a lone pair is a scene
of its prefix-1 pair alone. ``condition`` is the IntPhys 2 condition nearest to the concept
(``CONDITIONS``); a root per concept keeps the two concepts written as ``continuity`` apart.
Beside it, the same videos in the form the V-JEPA intuitive-physics surprise harness reads an
IntPhys 2 split (its ``intphys2_dataset.py``): ``labels.csv`` naming each video in a
``filename`` column, its frames as ``Images/<filename>/<NNN>.png``, lossless.

Videos are H.264 (libx264) in 4:4:4 YUV, lossless in YUV (qp 0) and without B-frames, so the
only error is the BT.601 RGB -> YUV -> RGB rounding (``MP4_ERROR``: at most 2 grey levels),
and a pair's identical prefix decodes to identical frames."""

from __future__ import annotations

import csv
import io
from fractions import Fraction
from typing import Any, cast

import numpy as np

from voe_lightning.benchmarks.intphys.export import png_bytes
from voe_lightning.benchmarks.intphys2 import reader
from voe_lightning.export.manifest import ExportFolder, Progress, Written, group_entry
from voe_lightning.export.probes import LABELS, ROLES, ProbeGroup, ProbePair, ProbeSource

#: The IntPhys 2 condition each concept is written as (``reader.CONDITIONS``'s keys); as
#: IntPhys' blocks, containment's is continuity: its cube stays behind when its container is
#: moved, where no path could have taken it.
CONDITIONS: dict[str, str] = {
    "object_persistence": "permanence",
    "unchangeableness": "immutability",
    "continuity": "continuity",
    "solidity": "solidity",
    "containment": "continuity",
}
#: What hides each concept's change (metadata.csv's ``occluder``).
OCCLUDERS: dict[str, str] = {
    "object_persistence": "plank",
    "unchangeableness": "screen",
    "continuity": "pillars",
    "solidity": "container",
    "containment": "container",
}
#: The labelled IntPhys 2 split the export imitates, and its columns.
SPLIT = "Main"
ENV = "MuJoCo"
#: The surprise harness's form: its labels file, whose ``filename`` column names each video's
#: frame folder under ``HARNESS_FRAMES``.
HARNESS_LABELS, HARNESS_FRAMES = "labels.csv", "Images"
#: How videos are encoded: fixed, so one store gives the same bytes on one machine.
MP4_CODEC = "libx264"
MP4_PIXEL_FORMAT = "yuv444p"
MP4_OPTIONS: dict[str, str] = {"qp": "0", "bf": "0", "preset": "medium"}
#: FFmpeg's colour tags of the stream (AVColorSpace SMPTE170M = BT.601, AVColorRange MPEG =
#: limited), what FFmpeg-based readers assume for untagged video too.
MP4_COLORSPACE, MP4_COLOR_RANGE = 6, 1
#: RGB -> limited-range BT.601 YCbCr (ITU-R BT.601, 8 bits): rows Y, Cb, Cr, then offsets.
BT601 = np.array([[65.481, 128.553, 24.966], [-37.797, -74.203, 112.0], [112.0, -93.786, -18.214]])
BT601_OFFSET = np.array([16.0, 128.0, 128.0])
#: The decoded frames' error in 0-255 units (PyAV's rgb24 decoding): measured over every 8-bit
#: RGB colour (largest 2) and on every concept's probes at 64x64 (mean 0.38, the worst video
#: 0.46), and asserted by tests/export.
MP4_ERROR: dict[str, float] = {"mean_absolute": 0.5, "max_absolute": 2}


def frame_rate(video: dict[str, Any]) -> Fraction:
    """The store's frames per second, num_frames over the duration (5 for 15 frames in 3 s)."""
    return Fraction(video["num_frames"]) / Fraction(video["duration"]).limit_denominator(1000)


def rgb_to_yuv444(image: np.ndarray) -> np.ndarray:
    """uint8 RGB [H, W, 3] -> planar limited-range BT.601 YCbCr [3, H, W], rounded in numpy
    (the same on every machine, unlike a SIMD conversion)."""
    yuv = np.einsum("ij,hwj->ihw", BT601 / 255, image.astype(np.float64))
    return cast(
        np.ndarray, np.clip(np.rint(yuv + BT601_OFFSET[:, None, None]), 0, 255).astype(np.uint8)
    )


def encode_mp4(frames: np.ndarray, rate: Fraction) -> bytes:
    """uint8 frames [T, H, W, 3] as the bytes of an mp4 (``MP4_*`` settings). PyAV is imported
    here, as the readers do, so the package imports without it."""
    import av

    buffer = io.BytesIO()
    with av.open(buffer, "w", format="mp4") as container:
        stream = container.add_stream(MP4_CODEC, rate=rate)
        assert isinstance(stream, av.VideoStream)
        stream.width, stream.height = frames.shape[2], frames.shape[1]
        stream.pix_fmt = MP4_PIXEL_FORMAT
        stream.options = dict(MP4_OPTIONS)
        stream.thread_count = 1
        stream.codec_context.colorspace = MP4_COLORSPACE
        stream.codec_context.color_range = MP4_COLOR_RANGE
        for index, image in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(rgb_to_yuv444(image), format=MP4_PIXEL_FORMAT)
            frame.pts = index
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))
    return buffer.getvalue()


def game_name(group: ProbeGroup) -> str:
    """metadata.csv's ``game_name``: the concept, with the change for unchangeableness'
    quadruplets (``unchangeableness_color``) and the variant for a lone pair."""
    if group.quadruplet is None:
        return f"{group.concept}_{group.pairs[0].variant}"
    change = group.quadruplet.removesuffix("quadruplet").rstrip("_")
    return f"{group.concept}_{change}" if change else group.concept


def video_rows(
    group: ProbeGroup, pair: ProbePair, record: Any, scene: int, prefix: str
) -> list[dict[str, str]]:
    """metadata.csv's rows of a pair's two videos (``Difficulty`` empty: none is rated)."""
    camera = record["camera"]
    fixed = bool((camera == camera[0]).all())
    rows = []
    for role in ROLES:
        name = pair.video_name(role)
        rows.append(
            {
                "SceneIndex": str(scene),
                "name": name,
                "file_name": f"Videos/{name}.mp4",
                "game_name": game_name(group),
                "condition": CONDITIONS[group.concept],
                "env": ENV,
                "type": f"{prefix}_{LABELS[role].capitalize()}",
                "occluder": OCCLUDERS[group.concept],
                "Difficulty": "",
                "Camera": "Fixed" if fixed else "Moving",
            }
        )
    return rows


def metadata_csv(rows: list[dict[str, str]]) -> bytes:
    """The rows as metadata.csv (UTF-8, ``\\n`` line ends)."""
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=reader.METADATA_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return text.getvalue().encode()


def labels_csv(rows: list[dict[str, str]]) -> bytes:
    """The rows as the surprise harness's labels.csv: metadata.csv's columns after
    ``filename``, the video's name (its folder under ``HARNESS_FRAMES``)."""
    text = io.StringIO()
    columns = ["filename", *reader.METADATA_COLUMNS]
    writer = csv.DictWriter(text, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows({"filename": row["name"], **row} for row in rows)
    return text.getvalue().encode()


def write_intphys2(source: ProbeSource, folder: ExportFolder, bar: Progress) -> Written:
    """Write ``source``'s groups in IntPhys 2's layout, one root per concept."""
    rate = frame_rate(source.video)
    written = Written(
        layout={
            "split_folder": SPLIT,
            "concepts": {c: {"root": c, "condition": CONDITIONS[c]} for c in source.concepts},
            "types": {
                "1_Possible": "A",
                "1_Impossible": "AB",
                "2_Possible": "B",
                "2_Impossible": "BA",
            },
            "video_location": "<concept>/Main/Videos/<name>.mp4, a row of "
            "<concept>/Main/metadata.csv; for the surprise harness also "
            "<concept>/Main/Images/<name>/NNN.png, a row of <concept>/Main/labels.csv "
            "(filename = name)",
        },
        encoding={
            "frames": f"mp4, H.264 ({MP4_CODEC}) {MP4_PIXEL_FORMAT}, options {MP4_OPTIONS}, "
            f"BT.601 limited range, {float(rate):g} fps; Images/<name>/NNN.png: PNG, lossless",
            "error_bound": MP4_ERROR,
            "masks": "not written (IntPhys 2 has none)",
            "labels": "metadata.csv type <prefix>_Possible (consistent) / _Impossible",
        },
    )
    rows: dict[str, list[dict[str, str]]] = {}
    scenes: dict[str, int] = {}
    for group, records in source.iterate():
        concept_rows = rows.setdefault(group.concept, [])
        scene = scenes[group.concept] = scenes.get(group.concept, -1) + 1
        locations = []
        for half, (pair, record) in enumerate(zip(group.pairs, records)):
            pair_rows = video_rows(group, pair, record, scene, reader.PREFIXES[half])
            concept_rows += pair_rows
            paths = [f"{group.concept}/{SPLIT}/{row['file_name']}" for row in pair_rows]
            for role, path, row in zip(ROLES, paths, pair_rows):
                frames = record[role, "frames"].numpy()
                folder.write(path, encode_mp4(frames, rate))
                images = f"{group.concept}/{SPLIT}/{HARNESS_FRAMES}/{row['name']}"
                for index, image in enumerate(frames):
                    folder.write(f"{images}/{index:03d}.png", png_bytes(image))
            locations.append(paths)
        written.groups.append(group_entry(group, records, locations, scene))
        bar.update(2 * len(group.pairs))
    for concept, concept_rows in rows.items():
        folder.write(f"{concept}/{SPLIT}/metadata.csv", metadata_csv(concept_rows))
        folder.write(f"{concept}/{SPLIT}/{HARNESS_LABELS}", labels_csv(concept_rows))
    return written
