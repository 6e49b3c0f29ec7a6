"""The IntPhys 2 benchmark (Bordes et al. 2025) read as our records: the released layout
``<root>/<split>/Videos/<name>.mp4`` with ``<root>/<split>/metadata.csv`` (columns
``SceneIndex, name, file_name, game_name, condition, env, type, occluder, Difficulty, Camera``;
the Debug split may call ``file_name`` ``filename``; the Held-Out split has no labels).

A row's ``type`` is ``<prefix>_Possible`` or ``<prefix>_Impossible`` (prefix 1 or 2): each scene
holds two possible/impossible pairs, and the Possible of a scene and prefix is paired with the
Impossible of the same scene and prefix into one of our probe records (consistent = possible,
``manipulation_frame`` = first sampled frame where the two differ). The scene's two pairs are
exposed as our stores expose a quadruplet: both carry ``seed`` = the scene's index in (condition,
scene) order, and the variant names the half, ``standard`` for prefix 1 and ``counterbalanced``
for prefix 2, so a report tests the scene's pairs together (``statistics.quadruplet_test``).
IntPhys 2 designs a scene's pairs so (the outcome possible in one pair is the impossible one in
the other, an obstacle or occluder deciding which), but its impossible videos are no splice of
its possible ones (docs/benchmarks.md). The principle comes from ``condition``; the difficulty
and camera are in the pairing table. Videos are decoded
with PyAV, sampled (every ``frame_step``-th frame from ``first_frame``, or spread evenly over
each video) and resized with PIL.
"""

from __future__ import annotations

import csv
import io
import os
import re
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torch.utils.data import Dataset

from voe_lightning import specs
from voe_lightning.benchmarks.mp4 import ClipSampling, read_video
from voe_lightning.benchmarks.reader import (
    BenchmarkDataError,
    SkipLog,
    first_divergence,
    read_text,
)

#: The columns of a labelled split's metadata.csv (the Main split's), in order.
METADATA_COLUMNS: tuple[str, ...] = tuple(
    "SceneIndex name file_name game_name condition env type occluder Difficulty Camera".split()
)
#: Concept vocabulary of IntPhys 2 records: the four principles.
PRINCIPLES: tuple[str, ...] = ("Permanence", "Immutability", "Continuity", "Solidity")
#: ``condition`` values of metadata.csv and their principle.
CONDITIONS: dict[str, str] = {
    "permanence": "Permanence",
    "immutability": "Immutability",
    "immutability_texture": "Immutability",
    "continuity": "Continuity",
    "continuity_swap": "Continuity",
    "solidity": "Solidity",
}
#: The Main split's difficulty (``unspecified`` where a row has none).
DIFFICULTIES: tuple[str, ...] = ("Easy", "Medium", "Hard", "unspecified")
#: Variant vocabulary of IntPhys 2 probe records: a scene's two pairs, by ``type`` prefix.
VARIANT_NAMES: tuple[str, ...] = specs.QUADRUPLET_VARIANTS
PREFIXES: tuple[str, ...] = ("1", "2")
#: What a probe record's seed and variant mean (cached records of another are decoded again):
#: 2, the scene's index and the pair's half; 1 was the pair's index, the difficulty.
RECORD_VERSION = 2
SPLITS: tuple[str, ...] = ("Debug", "Main", "HeldOut")
#: Labelled rows need these columns, besides the id column (``file_name`` or ``filename``).
LABEL_COLUMNS: tuple[str, ...] = ("SceneIndex", "condition", "type")
ID_COLUMNS: tuple[str, ...] = ("file_name", "filename")
_TYPE = re.compile(r"^([12])_(Possible|Impossible)$")


@dataclass(frozen=True)
class Video:
    """One row of metadata.csv (``row`` is its line number) and its file; the label fields are
    None for an unlabelled split."""

    path: Path
    name: str
    row: int
    scene: str | None = None
    prefix: str | None = None
    condition: str | None = None
    difficulty: str = "unspecified"
    camera: str = "unspecified"
    is_possible: bool | None = None

    @property
    def principle(self) -> str | None:
        return CONDITIONS.get(self.condition) if self.condition else None


@dataclass(frozen=True)
class Pair:
    """The Possible and the Impossible video of one scene and prefix; ``index`` is the scene's
    (the pair's seed), ``half`` its prefix's (the pair's variant)."""

    index: int
    possible: Video
    impossible: Video

    @property
    def half(self) -> int:
        return PREFIXES.index(self.possible.prefix)

    def entry(self, divergence: int) -> dict[str, Any]:
        """The pair's row of the pairing table (kept in the cache's manifest)."""
        p = self.possible
        return {
            "scene": p.scene,
            "prefix": p.prefix,
            "condition": p.condition,
            "principle": p.principle,
            "difficulty": p.difficulty,
            "camera": p.camera,
            "possible": p.name,
            "impossible": self.impossible.name,
            "possible_row": p.row,
            "impossible_row": self.impossible.row,
            "divergence_frame": divergence,
        }


# --- metadata ------------------------------------------------------------------------------------
def split_folder(root: str | os.PathLike[str], split: str) -> Path:
    if split not in SPLITS:
        raise ValueError(
            f"unknown IntPhys 2 split {split!r}; valid splits are: {', '.join(SPLITS)}"
        )
    folder = Path(root) / split
    if not folder.is_dir():
        raise FileNotFoundError(
            f"no IntPhys 2 {split} split at {folder}; expected {folder}/metadata.csv and "
            f"{folder}/Videos/<name>.mp4"
        )
    return folder


def _resolve(folder: Path, file_name: str) -> Path:
    """The video a metadata ``file_name`` names: relative to the split folder when it has a
    folder part (``Videos/x.mp4``), else in ``Videos/``; ``.mp4`` added when it has no suffix."""
    relative = Path(file_name)
    if not relative.suffix:
        relative = relative.with_suffix(".mp4")
    return folder / relative if len(relative.parts) > 1 else folder / "Videos" / relative


def _real(path: Path) -> Path:
    """``path`` with its links resolved; a link that loops is bad data, named."""
    try:
        return path.resolve()
    except (RuntimeError, OSError) as error:  # Python 3.11: RuntimeError("Symlink loop ...")
        raise BenchmarkDataError(
            f"{path} cannot be resolved ({error}): a symbolic link that points back at itself?",
            "bad_path",
        ) from None


def _row_video(
    folder: Path, csv_path: Path, number: int, row: dict[str, str], id_column: str, labelled: bool
) -> Video:
    where = f"{csv_path}, line {number}"
    file_name = (row.get(id_column) or "").strip()
    if not file_name:
        raise BenchmarkDataError(
            f"{where}: empty {id_column}; expected a video file name", "bad_row"
        )
    path = _resolve(folder, file_name)
    root = os.path.abspath(folder.parent)
    target = os.path.normpath(os.path.abspath(path))
    if os.path.commonpath([root, target]) != root:
        raise BenchmarkDataError(
            f"{where}: {id_column} {file_name!r} names {target}, outside the dataset root "
            f"{root}; a video is read from the dataset only: give its name in "
            f"{folder / 'Videos'} (x.mp4) or its path under {folder} (Videos/x.mp4)",
            "outside_root",
        )
    if not path.is_file():
        raise BenchmarkDataError(
            f"{where}: {id_column} {file_name!r} names {path}, which does not exist", "missing_file"
        )
    name = (row.get("name") or "").strip() or path.stem
    difficulty = (row.get("Difficulty") or "").strip().capitalize() or "unspecified"
    if difficulty not in DIFFICULTIES:
        raise BenchmarkDataError(
            f"{where}: unknown Difficulty {row.get('Difficulty')!r}; expected one of Easy, Medium, "
            "Hard (or empty)",
            "unknown_difficulty",
        )
    camera = (row.get("Camera") or "").strip() or "unspecified"
    if not labelled:
        return Video(path, name, number, difficulty=difficulty, camera=camera)
    condition = (row.get("condition") or "").strip()
    if condition not in CONDITIONS:
        raise BenchmarkDataError(
            f"{where}: unknown condition {condition!r}; expected one of {', '.join(CONDITIONS)}",
            "unknown_condition",
        )
    kind = _TYPE.match((row.get("type") or "").strip())
    if kind is None:
        raise BenchmarkDataError(
            f"{where}: unknown type {row.get('type')!r}; expected 1_Possible, 1_Impossible, "
            "2_Possible or 2_Impossible",
            "unknown_type",
        )
    scene = (row.get("SceneIndex") or "").strip()
    if not scene:
        raise BenchmarkDataError(
            f"{where}: empty SceneIndex; expected the scene's index", "bad_row"
        )
    return Video(
        path, name, number, scene, kind[1], condition, difficulty, camera, kind[2] == "Possible"
    )


def read_metadata(
    root: str | os.PathLike[str],
    split: str,
    labelled: bool = True,
    lenient: bool = False,
    skips: SkipLog | None = None,
) -> list[Video]:
    """The videos ``<split>/metadata.csv`` lists, in file order, each with its file checked
    (without metadata.csv, an unlabelled split lists every ``Videos/*.mp4``). A bad row (file
    missing, unknown condition or type) and a video with no row raise a BenchmarkDataError
    naming the file and line, or with ``lenient`` are logged to ``skips`` and left out."""
    folder = split_folder(root, split)
    csv_path = folder / "metadata.csv"
    if not csv_path.is_file():
        if labelled:
            raise FileNotFoundError(f"no {csv_path}; a labelled split needs its metadata.csv")
        return [Video(path, path.stem, 0) for path in sorted((folder / "Videos").glob("*.mp4"))]

    def refuse(error: BenchmarkDataError) -> None:
        if not lenient:
            raise error
        if skips is not None:
            skips.add(error.reason, str(error))

    with io.StringIO(read_text(csv_path, "bad_metadata"), newline="") as stream:
        reader = csv.DictReader(stream)
        columns = reader.fieldnames or []
        id_column = next((c for c in ID_COLUMNS if c in columns), None)
        missing = [c for c in LABEL_COLUMNS if c not in columns] if labelled else []
        if id_column is None or missing:
            raise BenchmarkDataError(
                f"{csv_path} has columns {columns}; expected {' or '.join(ID_COLUMNS)}"
                + (f" and {', '.join(LABEL_COLUMNS)}" if labelled else ""),
                "bad_metadata",
            )
        videos, listed = [], set()
        for row in reader:
            number = reader.line_num  # the row's (last) line: blank lines are skipped
            try:
                if (row.get(id_column) or "").strip():  # a bad row still names its file
                    listed.add(_real(_resolve(folder, row[id_column].strip())))
                videos.append(_row_video(folder, csv_path, number, row, id_column, labelled))
            except BenchmarkDataError as error:
                refuse(error)
    for path in sorted((folder / "Videos").glob("*.mp4")):
        try:
            unlisted = _real(path) not in listed
        except BenchmarkDataError as error:
            refuse(error)
            continue
        if unlisted:
            refuse(
                BenchmarkDataError(
                    f"{path} has no row in {csv_path}; every video needs one", "unlisted_file"
                )
            )
    return videos


def _scene_key(scene: str) -> tuple[tuple[int, int] | tuple[int, str], ...]:
    """Natural order of SceneIndex values (``2`` < ``10`` < ``10_0``)."""
    return tuple(
        (0, int(part)) if part.isdigit() else (1, part) for part in re.split(r"[_.]", scene)
    )


def pair_videos(
    videos: Iterable[Video], lenient: bool = False, skips: SkipLog | None = None
) -> list[Pair]:
    """Pair each Possible with the Impossible of the same condition, scene and prefix, in
    (condition, scene, prefix) order whatever the rows' order, each pair's ``index`` its
    scene's. A group that is not exactly one Possible and one Impossible raises, naming the
    scene and its rows, or with ``lenient`` is logged to ``skips`` and left out."""
    groups: dict[tuple[str, str, str], list[Video]] = defaultdict(list)
    for video in videos:
        condition, scene, prefix = video.condition, video.scene, video.prefix
        assert condition and scene and prefix, "a labelled video (read_metadata, labelled)"
        groups[(condition, scene, prefix)].append(video)
    pairs: list[Pair] = []
    scenes: dict[tuple[str, str], int] = {}
    for condition, scene, prefix in sorted(groups, key=lambda k: (k[0], _scene_key(k[1]), k[2])):
        group = groups[(condition, scene, prefix)]
        possible = [v for v in group if v.is_possible]
        impossible = [v for v in group if not v.is_possible]
        if len(possible) != 1 or len(impossible) != 1:
            rows = ", ".join(
                f"line {v.row} ({v.name}, {prefix}_{'Possible' if v.is_possible else 'Impossible'})"
                for v in group
            )
            error = BenchmarkDataError(
                f"scene {scene} ({condition}), prefix {prefix}: {len(possible)} Possible and "
                f"{len(impossible)} Impossible videos ({rows}); expected exactly one of each",
                "malformed_group",
            )
            if not lenient:
                raise error
            if skips is not None:
                skips.add(error.reason, str(error))
            continue
        index = scenes.setdefault((condition, scene), len(scenes))
        pairs.append(Pair(index, possible[0], impossible[0]))
    return pairs


def scene_pairs(pairs: Sequence[Pair]) -> list[list[Pair]]:
    """``pair_videos``'s pairs grouped by scene (by ``index``), in order."""
    scenes: dict[int, list[Pair]] = {}
    for pair in pairs:
        scenes.setdefault(pair.index, []).append(pair)
    return list(scenes.values())


# --- videos ---------------------------------------------------------------------------------------
class SceneDataset(Dataset[tuple[list[TensorDict], dict[str, Any] | None]]):
    """Item k: (the probe records of scene k's pairs, its pairing table entry: the variant of
    each pair -> the pair's entry). With ``lenient``, a scene with a pair that fails to decode
    is logged and yields ([], None)."""

    def __init__(
        self, pairs: Sequence[Pair], sampling: ClipSampling, lenient: bool, skips: SkipLog
    ):
        self.scenes, self.sampling = scene_pairs(pairs), sampling
        self.lenient, self.skips = lenient, skips

    def __len__(self) -> int:
        return len(self.scenes)

    def __getitem__(self, index: int) -> tuple[list[TensorDict], dict[str, Any] | None]:
        try:
            decoded = [self.decode(pair) for pair in self.scenes[index]]
        except BenchmarkDataError as error:
            if not self.lenient:
                raise
            self.skips.add(error.reason, str(error))
            return [], None
        return (
            [record for record, _ in decoded],
            {
                VARIANT_NAMES[pair.half]: entry
                for pair, (_, entry) in zip(self.scenes[index], decoded)
            },
        )

    def decode(self, pair: Pair) -> tuple[TensorDict, dict[str, Any]]:
        video = self.sampling.video
        possible = video.resize(read_video(pair.possible.path, self.sampling))
        impossible = video.resize(read_video(pair.impossible.path, self.sampling))
        divergence = first_divergence(
            possible, impossible, video.divergence_level, video.divergence_fraction
        )
        num_frames = self.sampling.num_frames
        if divergence >= num_frames:
            raise BenchmarkDataError(
                f"{pair.possible.path} and {pair.impossible.path} (scene {pair.possible.scene}, "
                f"prefix {pair.possible.prefix}) do not differ in any of their {num_frames} "
                "sampled frames; sample more frames (num_frames, frame_stride) or lower "
                "divergence_level / divergence_fraction",
                "no_divergence",
            )
        zeros = np.zeros((num_frames, video.height, video.width), np.uint8)
        record = specs.probe_record(
            (possible, zeros),
            (impossible, zeros),
            np.zeros((num_frames, 6), np.float32),
            concept=PRINCIPLES.index(pair.possible.principle),
            variant=pair.half,
            manipulation_frame=divergence,
            seed=pair.index,
        )
        return record, pair.entry(divergence)


class VideoDataset(Dataset[TensorDict]):
    """Single videos to score (``predict``): {frames [T, H, W, 3], index}, where
    ``names[index]`` is the video's name. Never lenient: a submission needs every video."""

    def __init__(self, videos: Sequence[Video], sampling: ClipSampling):
        self.videos, self.sampling = list(videos), sampling

    @property
    def names(self) -> list[str]:
        return [video.name for video in self.videos]

    def describe(self, index: int) -> str:
        """Video ``index`` as a user finds it: its file and metadata.csv line."""
        return f"{self.videos[index].path} (metadata.csv line {self.videos[index].row})"

    def __len__(self) -> int:
        return len(self.videos)

    def __getitem__(self, index: int) -> TensorDict:
        frames = self.sampling.video.resize(read_video(self.videos[index].path, self.sampling))
        return TensorDict(
            {"frames": torch.from_numpy(frames), "index": torch.tensor(index, dtype=torch.int64)},
            batch_size=[],
        )
