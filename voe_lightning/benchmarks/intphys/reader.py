"""The IntPhys benchmark (Riochet et al. 2018) read as our records: the released layout
``{dev,test}/O{1,2,3}/<scene>/{1,2,3,4}/scene/scene_001.png ...`` (plus ``status.json`` whose
``header.is_possible`` labels dev movies; ``depth/`` and ``masks/`` are not read) and the
optional ``train/<scene>/scene/`` movies.

Frames are subsampled to the model's sequence length and resized with PIL. Each scene is a
quadruplet of two possible and two impossible movies; every possible movie is paired with the
impossible movie it shares the longest prefix with, and the pair becomes one of our probe
records (consistent = possible, inconsistent = impossible, ``manipulation_frame`` = first
sampled frame where the two differ: the first *visible* difference, since the impossible event
itself may be hidden). The quadruplet is exposed as our stores expose theirs: both pairs carry
``seed = quadruplet_index`` and the variant names the half, ``standard`` for the pair of the
scene's first possible movie (A, AB) and ``counterbalanced`` for the second's (B, BA), so
reports test it by ``statistics.quadruplet_test`` (IntPhys splices each impossible movie from the
possible ones; the halves name no direction of the violation, only folder order). The scene's
condition (``CONDITIONS``) is in its pairing table entry. Single movies
(``MovieDataset``) are what ``predict`` scores into the challenge's answer.txt.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image
from tensordict import TensorDict
from torch.utils.data import Dataset

from voe_lightning import specs
from voe_lightning.benchmarks.reader import (
    BenchmarkDataError,
    FrameSampling,
    SkipLog,
    match_pairs,
    read_text,
)

BLOCKS: tuple[str, ...] = ("O1", "O2", "O3")
#: Concept vocabulary of IntPhys records: the three test blocks, then the training movies.
CONCEPT_NAMES: tuple[str, ...] = (
    "O1_object_permanence",
    "O2_shape_constancy",
    "O3_spatiotemporal_continuity",
    "train",
)
#: Conditions encoded in scene folder names (``0027_O1_test_visible_static_nobj3``); scenes
#: named by a bare number (the 2019 release) are ``unspecified``.
CONDITIONS: tuple[str, ...] = tuple(
    f"{visibility}_{motion}"
    for visibility in ("occluded", "visible")
    for motion in ("static", "dynamic_1", "dynamic_2")
) + ("unspecified",)
#: Variant vocabulary of IntPhys probe records: the two halves of a scene's quadruplet.
VARIANT_NAMES: tuple[str, ...] = specs.QUADRUPLET_VARIANTS
#: What a probe record's seed and variant mean (cached records of another are decoded again):
#: 2, the quadruplet index and the half; 1 was ``2 * quadruplet_index + pair``, the condition.
RECORD_VERSION = 2
MOVIES: tuple[str, ...] = ("1", "2", "3", "4")
SPLITS: tuple[str, ...] = ("train", "dev", "test")
_CONDITION = re.compile(r"(visible|occluded)_(static|dynamic_1|dynamic_2)")


@dataclass(frozen=True)
class Movie:
    """One movie folder; ``name`` is its path relative to the split folder (``O1/0001/1``)."""

    path: Path
    name: str
    is_possible: bool | None


@dataclass(frozen=True)
class Quadruplet:
    """The four movies of one scene."""

    index: int
    block: str
    scene: str
    condition: str
    movies: tuple[Movie, ...]


# --- reading the layout --------------------------------------------------------------------------
def frame_file(movie: Path, number: int) -> Path:
    """The PNG of frame ``number`` (1-based) of a movie folder."""
    return movie / "scene" / f"scene_{number:03d}.png"


def check_frames(movie: Path, frames_per_movie: int) -> None:
    """Raise unless ``movie/scene/`` holds exactly scene_001.png ... scene_<N>.png."""
    folder = movie / "scene"
    expected_range = (
        f"scene_001.png to scene_{frames_per_movie:03d}.png (frames_per_movie={frames_per_movie})"
    )
    if not folder.is_dir():
        raise BenchmarkDataError(
            f"movie {movie} has no scene/ folder; expected its frames {expected_range}",
            "missing_frame",
        )
    present = {p.name for p in folder.iterdir() if p.name.endswith(".png")}
    expected = {frame_file(movie, i).name for i in range(1, frames_per_movie + 1)}
    missing = sorted(expected - present)
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise BenchmarkDataError(
            f"missing frame {folder / missing[0]}{more}; expected {expected_range}", "missing_frame"
        )
    extra = sorted(present - expected)
    if extra:
        raise BenchmarkDataError(
            f"unexpected frame {folder / extra[0]}: movie holds {len(present)} PNGs, expected "
            f"{expected_range}",
            "unexpected_frame",
        )


def read_label(movie: Path) -> bool:
    """``header.is_possible`` of ``movie/status.json``."""
    path = movie / "status.json"
    try:
        header = json.loads(read_text(path, "missing_label"))["header"]
        label = header["is_possible"]
    except BenchmarkDataError:
        raise  # not UTF-8: read_text names the line
    except FileNotFoundError:
        raise BenchmarkDataError(
            f"missing {path}: labelled (dev) movies need status.json with header.is_possible",
            "missing_label",
        ) from None
    except (ValueError, KeyError, TypeError) as error:
        raise BenchmarkDataError(
            f"{path} has no header.is_possible ({type(error).__name__}: {error}); expected "
            '{"header": {"is_possible": true|false, ...}, ...}',
            "missing_label",
        ) from None
    if not isinstance(label, bool):
        raise BenchmarkDataError(
            f"{path}: header.is_possible is {label!r}, expected true or false", "missing_label"
        )
    return label


#: PIL modes of a 16-bit grayscale PNG (``I`` from older Pillow versions): scaled to 8 bits.
GRAY16_MODES = ("I", "I;16", "I;16B", "I;16L", "I;16N")


def read_png(path: Path) -> np.ndarray:
    """One frame as uint8 [h, w, 3]; a missing or undecodable file names itself. A 16-bit
    grayscale PNG is scaled to 8 bits (v / 257, rounded: 65535 is 255), not clipped at 255
    as PIL's ``convert("RGB")`` does."""
    try:
        with Image.open(path) as image:
            image.load()
            if image.mode in GRAY16_MODES:
                gray = np.asarray(image).astype(np.int64)
                if gray.min() < 0 or gray.max() > 65535:
                    raise BenchmarkDataError(
                        f"unreadable PNG {path}: mode {image.mode} holds values "
                        f"{gray.min()}..{gray.max()}, beyond 16 bits; expected an RGB PNG frame",
                        "unreadable_png",
                    )
                level = ((gray * 255 + 32767) // 65535).astype(np.uint8)
                return np.repeat(level[..., None], 3, axis=-1)
            return np.asarray(image.convert("RGB"))
    except BenchmarkDataError:
        raise
    except FileNotFoundError:
        raise BenchmarkDataError(f"missing frame {path}", "missing_frame") from None
    except Image.DecompressionBombError as error:
        raise BenchmarkDataError(
            f"unreadable PNG {path}: its header claims a frame too large to decode safely "
            f"({error}); expected an RGB PNG frame",
            "unreadable_png",
        ) from None
    except (OSError, SyntaxError, ValueError) as error:
        raise BenchmarkDataError(
            f"unreadable PNG {path} ({error}); expected an RGB PNG frame", "unreadable_png"
        ) from None


def read_movie(movie: Path, indices: Sequence[int]) -> np.ndarray:
    """Frames ``indices`` (0-based) of a movie at full resolution: uint8 [T, h, w, 3]."""
    frames = [read_png(frame_file(movie, int(i) + 1)) for i in indices]
    for index, frame in zip(indices, frames):
        if frame.shape != frames[0].shape:
            raise BenchmarkDataError(
                f"frame {frame_file(movie, int(index) + 1)} is {frame.shape[1]}x{frame.shape[0]}, "
                f"expected {frames[0].shape[1]}x{frames[0].shape[0]} like the movie's first frame",
                "frame_size",
            )
    return np.stack(frames)


def condition_of(scene: str) -> str:
    """The condition a scene folder's name encodes (``CONDITIONS``)."""
    match = _CONDITION.search(scene)
    return f"{match[1]}_{match[2]}" if match else "unspecified"


def _subfolders(path: Path) -> list[Path]:
    return sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))


def split_folder(root: str | os.PathLike[str], split: str) -> Path:
    if split not in SPLITS:
        raise ValueError(f"unknown IntPhys split {split!r}; valid splits are: {', '.join(SPLITS)}")
    folder = Path(root) / split
    if not folder.is_dir():
        raise FileNotFoundError(
            f"no IntPhys {split} set at {folder}; expected {folder}/O1/<scene>/1/scene/scene_001.png ..."
            if split != "train"
            else f"no IntPhys train set at {folder}; expected {folder}/<scene>/scene/scene_001.png ..."
        )
    return folder


def scan_quadruplets(
    root: str | os.PathLike[str],
    split: str,
    frames_per_movie: int,
    labelled: bool,
    lenient: bool = False,
    skips: SkipLog | None = None,
) -> list[Quadruplet]:
    """Every scene of ``split`` whose layout is complete (frame files present, 4 movies, and for
    a labelled split 2 possible + 2 impossible). Malformed scenes raise, or with ``lenient``
    are logged to ``skips`` and left out."""
    folder = split_folder(root, split)
    blocks = [folder / block for block in BLOCKS if (folder / block).is_dir()]
    if not blocks:
        raise FileNotFoundError(f"{folder} holds none of the block folders {', '.join(BLOCKS)}")
    quadruplets: list[Quadruplet] = []
    for block in blocks:
        for scene in _subfolders(block):
            try:
                quadruplets.append(
                    _scan_scene(scene, block.name, len(quadruplets), frames_per_movie, labelled)
                )
            except BenchmarkDataError as error:
                if not lenient:
                    raise
                if skips is not None:
                    skips.add(error.reason, f"{scene}: {error}")
    return quadruplets


def _scan_scene(
    scene: Path, block: str, index: int, frames_per_movie: int, labelled: bool
) -> Quadruplet:
    names = [p.name for p in _subfolders(scene)]
    if sorted(names) != list(MOVIES):
        raise BenchmarkDataError(
            f"scene {scene} holds movies {names}; expected exactly the 4 movies 1, 2, 3, 4",
            "wrong_movie_count",
        )
    movies = []
    for name in MOVIES:
        check_frames(scene / name, frames_per_movie)
        label = read_label(scene / name) if labelled else None
        movies.append(Movie(scene / name, f"{block}/{scene.name}/{name}", label))
    if labelled:
        possible = sum(bool(movie.is_possible) for movie in movies)
        if possible != 2:
            raise BenchmarkDataError(
                f"scene {scene} has {possible} possible and {4 - possible} impossible movies "
                "(header.is_possible); expected 2 and 2",
                "wrong_label_count",
            )
    return Quadruplet(
        index, block, f"{block}/{scene.name}", condition_of(scene.name), tuple(movies)
    )


def scan_train(
    root: str | os.PathLike[str],
    frames_per_movie: int,
    lenient: bool = False,
    skips: SkipLog | None = None,
) -> list[Path]:
    """The training movie folders (``train/<scene>/scene/...``) whose frames are complete."""
    movies = []
    for movie in _subfolders(split_folder(root, "train")):
        try:
            check_frames(movie, frames_per_movie)
            movies.append(movie)
        except BenchmarkDataError as error:
            if not lenient:
                raise
            if skips is not None:
                skips.add(error.reason, f"{movie}: {error}")
    return movies


# --- datasets ------------------------------------------------------------------------------------
class QuadrupletDataset(Dataset[tuple[list[TensorDict], dict[str, Any] | None]]):
    """Item q: (the two probe records of quadruplet q, its pairing table entry). With
    ``lenient``, a quadruplet that fails to decode or pair is logged and yields no records."""

    def __init__(
        self, quadruplets: Sequence[Quadruplet], video: FrameSampling, lenient: bool, skips: SkipLog
    ):
        self.quadruplets, self.video, self.lenient, self.skips = (
            list(quadruplets),
            video,
            lenient,
            skips,
        )

    def __len__(self) -> int:
        return len(self.quadruplets)

    def __getitem__(self, index: int) -> tuple[list[TensorDict], dict[str, Any] | None]:
        quadruplet = self.quadruplets[index]
        try:
            return self.decode(quadruplet)
        except BenchmarkDataError as error:
            if not self.lenient:
                raise
            self.skips.add(error.reason, f"{quadruplet.scene}: {error}")
            return [], None

    def decode(self, quadruplet: Quadruplet) -> tuple[list[TensorDict], dict[str, Any]]:
        video = self.video
        full = {m.name: read_movie(m.path, video.indices) for m in quadruplet.movies}
        shapes = {name: frames.shape for name, frames in full.items()}
        if len(set(shapes.values())) > 1:
            raise BenchmarkDataError(
                f"scene {quadruplet.scene}: movies have different frame sizes {shapes}; expected one size",
                "frame_size",
            )
        possible = [m for m in quadruplet.movies if m.is_possible]
        impossible = [m for m in quadruplet.movies if not m.is_possible]
        pairs, ambiguous = match_pairs(
            [full[m.name] for m in possible],
            [full[m.name] for m in impossible],
            video.divergence_level,
            video.divergence_fraction,
        )
        num_frames = len(video.indices)
        zeros_mask = np.zeros((num_frames, video.height, video.width), np.uint8)
        camera = np.zeros((num_frames, 6), np.float32)  # IntPhys poses are not in our convention
        records, table = [], []
        for number, (p, i, divergence) in enumerate(pairs):
            if divergence >= num_frames:
                raise BenchmarkDataError(
                    f"scene {quadruplet.scene}: possible movie {possible[p].name} and impossible movie "
                    f"{impossible[i].name} do not differ in any of the {num_frames} sampled frames "
                    f"{list(video.indices)}; sample more frames (num_frames, frame_stride) or lower "
                    "divergence_level / divergence_fraction",
                    "no_divergence",
                )
            records.append(
                specs.probe_record(
                    (video.resize(full[possible[p].name]), zeros_mask),
                    (video.resize(full[impossible[i].name]), zeros_mask),
                    camera,
                    concept=BLOCKS.index(quadruplet.block),
                    variant=number,
                    manipulation_frame=divergence,
                    seed=quadruplet.index,
                )
            )
            table.append(
                {
                    "possible": possible[p].name,
                    "impossible": impossible[i].name,
                    "divergence_frame": divergence,
                    "divergence_source_frame": int(video.indices[divergence]),
                }
            )
        entry = {
            "block": quadruplet.block,
            "scene": quadruplet.scene,
            "condition": quadruplet.condition,
            "ambiguous_pairing": ambiguous,
            "pairs": table,
        }
        return records, entry


class MovieDataset(Dataset[TensorDict]):
    """Single movies to score (``predict``): {frames [T, H, W, 3], index}, where
    ``names[index]`` is the movie's answer.txt path (``O1/0001/1``). Never lenient: a
    submission needs a score for every movie."""

    def __init__(self, movies: Sequence[Movie], video: FrameSampling):
        self.movies, self.video = list(movies), video

    @property
    def names(self) -> list[str]:
        return [movie.name for movie in self.movies]

    def __len__(self) -> int:
        return len(self.movies)

    def __getitem__(self, index: int) -> TensorDict:
        frames = self.video.resize(read_movie(self.movies[index].path, self.video.indices))
        return TensorDict(
            {
                "frames": torch.from_numpy(frames),
                "index": torch.tensor(index, dtype=torch.int64),
            },
            batch_size=[],
        )


class TrainClipDataset(Dataset[TensorDict | None]):
    """IntPhys training movies (all possible) as clips: concept ``train``, kind 0 (``example``),
    zero masks and cameras, seed = movie index. With ``lenient``, an undecodable movie is
    logged and replaced by the next readable one (``substitute``) or returned as None."""

    def __init__(
        self,
        movies: Sequence[Path],
        video: FrameSampling,
        lenient: bool,
        skips: SkipLog,
        substitute: bool = True,
    ):
        self.movies, self.video, self.lenient, self.skips = list(movies), video, lenient, skips
        self.substitute = substitute

    def __len__(self) -> int:
        return len(self.movies)

    def clip(self, index: int) -> TensorDict:
        video = self.video
        frames = video.resize(read_movie(self.movies[index], video.indices))
        num_frames = len(video.indices)
        return specs.clip_record(
            frames,
            np.zeros((num_frames, video.height, video.width), np.uint8),
            np.zeros((num_frames, 6), np.float32),
            concept=CONCEPT_NAMES.index("train"),
            kind=0,
            seed=index,
        )

    def __getitem__(self, index: int) -> TensorDict | None:
        for attempt in range(len(self.movies)):
            current = (index + attempt) % len(self.movies)
            try:
                return self.clip(current)
            except BenchmarkDataError as error:
                if not self.lenient:
                    raise
                self.skips.add(error.reason, f"{self.movies[current]}: {error}")
                if not self.substitute:
                    return None
        raise BenchmarkDataError(
            f"no readable training movie among {len(self.movies)}", "unreadable_png"
        )
