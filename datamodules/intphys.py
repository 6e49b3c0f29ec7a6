"""IntPhys (Riochet et al. 2018) as a LightningDataModule: the released layout
``{dev,test}/O{1,2,3}/<scene>/{1,2,3,4}/scene/scene_001.png ...`` (plus ``status.json`` whose
``header.is_possible`` labels dev movies; ``depth/`` and ``masks/`` are not read) and the
optional ``train/<scene>/scene/`` movies.

Frames are subsampled to the model's sequence length and resized with PIL. Each scene is a
quadruplet of two possible and two impossible movies; every possible movie is paired with the
impossible movie it shares the longest prefix with, and the pair becomes one of our probe
records (consistent = possible, inconsistent = impossible, ``manipulation_frame`` = first
sampled frame where the two differ: the first *visible* difference, since the impossible event
itself may be hidden). ``seed = pair_index = 2 * quadruplet_index + pair``; the quadruplet
table (scene, movie paths, divergence frames) is ``IntPhysDataModule.quadruplets(split)``.
The unlabelled test movies are scored by ``write_answer`` into the challenge's answer.txt.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image
from tensordict import TensorDict
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from datamodules.arguments import check_at_least, check_fraction
from datamodules.benchmark_data import (
    BenchmarkDataError,
    BenchmarkDataModule,
    RecordList,
    SkipLog,
    VideoOptions,
    clip_record,
    fingerprint,
    match_pairs,
    open_cache,
    probe_record,
    write_cache,
)
from voe_lightning import specs
from voe_lightning.benchmark_metrics import grouped_metrics, write_answer_file
from voe_lightning.store import probe_sampler

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
VARIANT_NAMES: tuple[str, ...] = tuple(
    f"{visibility}_{motion}"
    for visibility in ("occluded", "visible")
    for motion in ("static", "dynamic_1", "dynamic_2")
) + ("unspecified",)
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
    variant: str
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
        header = json.loads(path.read_text())["header"]
        label = header["is_possible"]
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


def read_png(path: Path) -> np.ndarray:
    """One frame as uint8 [h, w, 3]; a missing or undecodable file names itself."""
    try:
        with Image.open(path) as image:
            image.load()
            return np.asarray(image.convert("RGB"))
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


def variant_of(scene: str) -> str:
    match = _CONDITION.search(scene)
    return f"{match[1]}_{match[2]}" if match else "unspecified"


def _subfolders(path: Path) -> list[Path]:
    return sorted(p for p in path.iterdir() if p.is_dir() and not p.name.startswith("."))


def split_folder(root: str | os.PathLike, split: str) -> Path:
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
    root: str | os.PathLike,
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
        possible = sum(movie.is_possible for movie in movies)
        if possible != 2:
            raise BenchmarkDataError(
                f"scene {scene} has {possible} possible and {4 - possible} impossible movies "
                "(header.is_possible); expected 2 and 2",
                "wrong_label_count",
            )
    return Quadruplet(index, block, f"{block}/{scene.name}", variant_of(scene.name), tuple(movies))


def scan_train(
    root: str | os.PathLike,
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
class QuadrupletDataset(Dataset):
    """Item q: (the two probe records of quadruplet q, its pairing table entry). With
    ``lenient``, a quadruplet that fails to decode or pair is logged and yields no records."""

    def __init__(
        self, quadruplets: Sequence[Quadruplet], video: VideoOptions, lenient: bool, skips: SkipLog
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
                probe_record(
                    (video.resize(full[possible[p].name]), zeros_mask),
                    (video.resize(full[impossible[i].name]), zeros_mask),
                    camera,
                    concept=BLOCKS.index(quadruplet.block),
                    variant=VARIANT_NAMES.index(quadruplet.variant),
                    manipulation_frame=divergence,
                    quadruplet_index=quadruplet.index,
                    pair_in_quadruplet=number,
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
            "variant": quadruplet.variant,
            "ambiguous_pairing": ambiguous,
            "pairs": table,
        }
        return records, entry


class MovieDataset(Dataset):
    """Single movies for scoring (answer.txt): {frames [T, H, W, 3], movie_index}. Never
    lenient: a submission needs a score for every movie."""

    def __init__(self, movies: Sequence[Movie], video: VideoOptions):
        self.movies, self.video = list(movies), video

    def __len__(self) -> int:
        return len(self.movies)

    def __getitem__(self, index: int) -> TensorDict:
        frames = self.video.resize(read_movie(self.movies[index].path, self.video.indices))
        return TensorDict(
            {
                "frames": torch.from_numpy(frames),
                "movie_index": torch.tensor(index, dtype=torch.int64),
            },
            batch_size=[],
        )


class TrainClipDataset(Dataset):
    """IntPhys training movies (all possible) as clips: concept ``train``, kind 0 (``example``),
    zero masks and cameras, seed = movie index. With ``lenient``, an undecodable movie is
    logged and replaced by the next readable one (``substitute``) or returned as None."""

    def __init__(
        self,
        movies: Sequence[Path],
        video: VideoOptions,
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
        return clip_record(
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


def _identity(item: Any) -> Any:
    return item


# --- the DataModule -----------------------------------------------------------------------------
class IntPhysDataModule(BenchmarkDataModule):
    """IntPhys for ``fit`` (training movies of ``train/`` as clips, dev probes for validation),
    ``validate``/``test`` (probe pairs of ``eval_split``, default the labelled dev set) and
    ``predict`` (single movies of ``predict_split``, default the unlabelled test set; see
    ``write_answer``).

    Args:
        root: folder holding ``dev/``, ``test/`` and optionally ``train/``.
        batch_size: clips per training batch.
        probe_batch_size: probe pairs (or movies) per evaluation batch.
        num_workers: DataLoader worker processes (also used to decode the probes in ``setup``).
        num_frames, height, width: model input geometry; frames are resized with PIL.
            None (default): the model's, resolved in ``setup`` (its ``training_frames`` and
            ``image_size`` hyperparameters, from the checkpoint under ``test --ckpt_path``).
        frames_per_movie: frames in every movie folder (IntPhys: 100).
        frame_stride, first_frame: sample every ``frame_stride``-th frame from ``first_frame``;
            by default ``num_frames`` frames spread evenly over the whole movie.
        divergence_level, divergence_fraction: a frame differs when more than this fraction of
            its pixels differ by more than this many grey levels (tolerates renderer noise).
        eval_split: split of the validation and test probes (needs labels: ``dev``).
        predict_split: split whose movies ``predict_dataloader``/``write_answer`` score.
        lenient: skip malformed scenes and movies instead of raising; ``skipped`` counts them.
        cache_dir: if set, decoded records are written there once (store shards) and reused.
        seed: seed of the training order.
    """

    concept_names, variant_names = CONCEPT_NAMES, VARIANT_NAMES

    def __init__(
        self,
        root: str = "data/intphys",
        batch_size: int = 10,
        probe_batch_size: int = 32,
        num_workers: int = 0,
        num_frames: int | None = None,
        height: int | None = None,
        width: int | None = None,
        frames_per_movie: int = 100,
        frame_stride: int | None = None,
        first_frame: int = 0,
        divergence_level: int = 10,
        divergence_fraction: float = 0.001,
        eval_split: str = "dev",
        predict_split: str = "test",
        lenient: bool = False,
        cache_dir: str | None = None,
        seed: int = 0,
    ):
        super().__init__()
        check_at_least(
            {
                "batch_size": (batch_size, 1),
                "probe_batch_size": (probe_batch_size, 1),
                "height": (height, 1),
                "width": (width, 1),
                "num_workers": (num_workers, 0),
                "num_frames": (num_frames, 1),
                "frames_per_movie": (frames_per_movie, 1),
                "frame_stride": (frame_stride, 1),
                "first_frame": (first_frame, 0),
                "divergence_level": (divergence_level, 0),
            }
        )
        check_fraction("divergence_fraction", divergence_fraction)
        for name, split in [("eval_split", eval_split), ("predict_split", predict_split)]:
            if split not in ("dev", "test"):
                raise ValueError(f"{name} must be 'dev' or 'test', got {split!r}")
        if eval_split == "test":
            raise ValueError("eval_split='test' has no labels to pair movies by; use 'dev'")
        self.save_hyperparameters()
        self.source_frames = frames_per_movie
        self._resolve_video(required=False)
        self._probes: dict[str, Dataset] = {}
        self._tables: dict[str, dict[int, dict[str, Any]]] = {}
        self._train: Dataset | None = None
        self._movies: dict[str, list[Movie]] = {}

    # --- building --------------------------------------------------------------------------------
    def setup(self, stage: str | None = None) -> None:
        self._resolve_video()
        h = self.hparams
        if stage in ("fit", None):
            self._setup_train()
        if stage in ("fit", "validate", "test", None):
            self.probes(h.eval_split)
        if stage == "predict":
            self.movies(h.predict_split)

    def _settings(self, what: str) -> dict[str, Any]:
        h = self.hparams
        return {
            "what": what,
            "video": self.video.__dict__,
            "frames_per_movie": h.frames_per_movie,
            "lenient": h.lenient,
        }

    def _cache_folder(self, what: str, sources: list[Path]) -> Path | None:
        if self.hparams.cache_dir is None:
            return None
        key = fingerprint(self._settings(what), sources)
        return Path(self.hparams.cache_dir) / "intphys" / what / key

    def probes(self, split: str = "dev") -> Dataset:
        """The probe pairs of a labelled split (decoded once; from the cache when there is one)."""
        if split in self._probes:
            return self._probes[split]
        h = self.hparams
        skips = self._skips[split] = SkipLog()
        quadruplets = scan_quadruplets(h.root, split, h.frames_per_movie, True, h.lenient, skips)
        sources = [
            p
            for q in quadruplets
            for m in q.movies
            for p in (m.path / "scene", m.path / "status.json")
        ]
        folder = self._cache_folder(split, sources)
        required = {"table": dict, "skipped": dict}
        cached = open_cache(folder, required) if folder is not None else None
        if cached is not None:  # its counts already include this scan's skips
            self._skips[split] = SkipLog()
            self._cached_skips[split] = cached.meta.get("skipped", {})
            self._tables[split] = {int(k): v for k, v in cached.meta["table"].items()}
            self._probes[split] = cached
            return cached
        meta: dict[str, Any] = {"table": {}}
        records = self._decode(
            QuadrupletDataset(quadruplets, self.video, h.lenient, skips), meta, skips, split
        )
        self._probes[split] = (
            RecordList(list(records)) if folder is None else write_cache(folder, records, meta)
        )
        self._tables[split] = meta["table"]
        return self._probes[split]

    def _decode(
        self, dataset: QuadrupletDataset, meta: dict, skips: SkipLog, split: str
    ) -> Iterator[TensorDict]:
        """The probe records, decoded by worker processes; fills ``meta`` (quadruplet table,
        skipped counts) as it goes, complete once exhausted."""
        loader = DataLoader(
            dataset, batch_size=None, num_workers=self.hparams.num_workers, collate_fn=_identity
        )
        for records, entry in tqdm(
            loader, desc=f"decoding IntPhys {split}", unit="scene", leave=False
        ):
            if entry is not None:
                meta["table"][records[0]["quadruplet_index"].item()] = entry
            yield from records
        meta["skipped"] = skips.counts()

    def quadruplets(self, split: str = "dev") -> dict[int, dict[str, Any]]:
        """quadruplet_index -> {block, scene, variant, ambiguous_pairing, pairs: [{possible,
        impossible, divergence_frame, divergence_source_frame}]} (pair j has seed 2q + j)."""
        self.probes(split)
        return self._tables[split]

    def _setup_train(self) -> None:
        if self._train is not None:
            return
        h = self.hparams
        skips = self._skips["train"] = SkipLog()
        movies = scan_train(h.root, h.frames_per_movie, h.lenient, skips)
        folder = self._cache_folder("train", [m / "scene" for m in movies])
        if folder is None:
            self._train = TrainClipDataset(movies, self.video, h.lenient, skips, substitute=True)
            return
        cached = open_cache(folder, {"skipped": dict})
        if cached is None:
            converting = TrainClipDataset(movies, self.video, h.lenient, skips, substitute=False)
            meta: dict[str, Any] = {}
            cached = write_cache(folder, self._convert(converting, meta, skips), meta)
        self._skips["train"] = SkipLog()
        self._cached_skips["train"] = cached.meta.get("skipped", {})
        self._train = cached

    def _convert(
        self, dataset: TrainClipDataset, meta: dict, skips: SkipLog
    ) -> Iterator[TensorDict]:
        loader = DataLoader(
            dataset, batch_size=None, num_workers=self.hparams.num_workers, collate_fn=_identity
        )
        for record in tqdm(loader, desc="caching IntPhys train", unit="movie", leave=False):
            if record is not None:
                yield record
        meta["skipped"] = skips.counts()

    def movies(self, split: str = "test") -> list[Movie]:
        """Every movie of ``split`` in answer.txt order (labels are None for ``test``)."""
        if split not in self._movies:
            h = self.hparams
            quadruplets = scan_quadruplets(h.root, split, h.frames_per_movie, split == "dev")
            self._movies[split] = sorted(
                (m for q in quadruplets for m in q.movies), key=lambda m: m.name
            )
        return self._movies[split]

    def probe_cases(self, split: str = "val") -> list[tuple[str, str]]:
        """The (concept, variant) names present among the evaluation probes."""
        table = self.quadruplets(self.hparams.eval_split)
        return sorted(
            {(CONCEPT_NAMES[BLOCKS.index(e["block"])], e["variant"]) for e in table.values()}
        )

    # --- loaders ---------------------------------------------------------------------------------
    def train_dataloader(self) -> DataLoader:
        self._setup_train()
        generator = torch.Generator().manual_seed(self.hparams.seed)
        return self._loader(
            self._train, self.hparams.batch_size, shuffle=True, drop_last=True, generator=generator
        )

    def val_dataloader(self) -> DataLoader:
        probes = self.probes(self.hparams.eval_split)
        return self._loader(probes, self.hparams.probe_batch_size, sampler=probe_sampler(probes))

    def test_dataloader(self) -> DataLoader:
        return self.val_dataloader()

    def predict_dataloader(self) -> DataLoader:
        dataset = MovieDataset(self.movies(self.hparams.predict_split), self.video)
        return self._loader(dataset, self.hparams.probe_batch_size,
                            sampler=probe_sampler(dataset))

    # --- evaluation ------------------------------------------------------------------------------
    def _pair_rows(
        self, outputs: dict[str, Any]
    ) -> tuple[np.ndarray, list[dict[str, Any]], list[dict[str, Any]]]:
        table = self.quadruplets(self.hparams.eval_split)
        seeds = np.asarray(torch.as_tensor(outputs["seed"]).cpu()).ravel()
        entries, pairs = [], []
        for seed in seeds.tolist():
            if seed // 2 not in table:
                raise KeyError(f"seed {seed} names no IntPhys {self.hparams.eval_split} probe pair")
            entries.append(table[seed // 2])
            pairs.append(table[seed // 2]["pairs"][seed % 2])
        return seeds, entries, pairs

    def benchmark_metrics(self, outputs: dict[str, Any], **options: Any) -> dict[str, Any]:
        """IntPhys metrics per block (``all``, and ``visible`` / ``occluded`` when scene names say)
        from collected ``probe_step`` outputs (seed, surprise_consistent, surprise_inconsistent
        [N, T]); a movie's surprise is its sum over frames. ``options`` go to
        ``benchmark_metrics.quadruplet_metrics`` (alpha, bootstrap)."""
        seeds, entries, _ = self._pair_rows(outputs)
        possible = torch.as_tensor(outputs["surprise_consistent"]).double().sum(-1).cpu().numpy()
        impossible = (
            torch.as_tensor(outputs["surprise_inconsistent"]).double().sum(-1).cpu().numpy()
        )
        groups = [CONCEPT_NAMES[BLOCKS.index(e["block"])] for e in entries]
        visibility = [
            e["variant"].split("_")[0] if e["variant"] != "unspecified" else None for e in entries
        ]
        quadruplet = seeds // 2
        counts = np.bincount(quadruplet)
        return {
            "benchmark": "IntPhys",
            "split": self.hparams.eval_split,
            "metrics": grouped_metrics(
                groups, quadruplet, possible, impossible, visibility, **options
            ),
            "incomplete_quadruplets": len({int(q) for q in quadruplet if counts[q] != 2}),
            "ambiguous_pairings": len(
                {int(q) for q, e in zip(quadruplet, entries) if e["ambiguous_pairing"]}
            ),
            "skipped": self.skipped,
        }

    def movie_surprise(self, outputs: dict[str, Any]) -> dict[str, float]:
        """Each movie's total surprise (movie path -> float) from probe_step outputs."""
        _, _, pairs = self._pair_rows(outputs)
        possible = torch.as_tensor(outputs["surprise_consistent"]).double().sum(-1).tolist()
        impossible = torch.as_tensor(outputs["surprise_inconsistent"]).double().sum(-1).tolist()
        result = {}
        for pair, p, i in zip(pairs, possible, impossible):
            result[pair["possible"]], result[pair["impossible"]] = p, i
        return result

    @torch.no_grad()
    def score_movies(self, model: Any, split: str | None = None) -> dict[str, float]:
        """Total surprise of every movie of ``split`` under ``model.surprise`` (movie path ->
        float), in evaluation mode; the batch's ``mask`` goes along when the movies have one."""
        split = split or self.hparams.predict_split
        movies = self.movies(split)
        loader = self._loader(MovieDataset(movies, self.video), self.hparams.probe_batch_size)
        device = getattr(model, "device", "cpu")
        was_training = getattr(model, "training", False)
        if hasattr(model, "eval"):
            model.eval()
        scores = {}
        try:
            for batch in tqdm(loader, desc=f"scoring IntPhys {split}", unit="batch", leave=False):
                masks = {"mask": batch["mask"].to(device)} if "mask" in batch.keys() else {}
                surprise = model.surprise(batch["frames"].to(device), **masks)
                surprise = surprise.double().sum(-1).cpu()
                for index, value in zip(batch["movie_index"].tolist(), surprise.tolist()):
                    scores[movies[index].name] = value
        finally:
            if was_training:
                model.train()
        return scores

    def write_answer(self, model: Any, path: str | os.PathLike, split: str | None = None) -> Path:
        """Score every movie of ``split`` (default ``predict_split``) and write the challenge's
        answer.txt (``<movie path> <plausibility>`` lines) to ``path``."""
        return write_answer_file(path, self.score_movies(model, split))


def answer_main(argv: list[str] | None = None) -> Path:
    """``python -m voe_lightning intphys-answer --ckpt_path CKPT --root DIR [--out answer.txt]``:
    score the unlabelled IntPhys test movies with a trained model into the challenge's file."""
    import argparse

    from voe_lightning.model import VOEModel

    parser = argparse.ArgumentParser(
        prog="python -m voe_lightning intphys-answer", description=answer_main.__doc__
    )
    parser.add_argument("--ckpt_path", required=True, help="checkpoint of a trained VOEModel")
    parser.add_argument("--root", default="data/intphys", help="IntPhys folder holding test/")
    parser.add_argument("--out", default="answer.txt", help="submission file to write")
    parser.add_argument("--num-frames", type=int, default=specs.NUM_FRAMES)
    parser.add_argument("--frames-per-movie", type=int, default=100)
    parser.add_argument("--split", choices=("dev", "test"), default="test")
    arguments = parser.parse_args(argv)
    if not Path(arguments.ckpt_path).is_file():
        parser.error(f"--ckpt_path {arguments.ckpt_path!r} does not exist")
    model = VOEModel.load_from_checkpoint(arguments.ckpt_path, map_location="cpu", weights_only=True).eval()
    height, width = model.image_size
    datamodule = IntPhysDataModule(
        root=arguments.root,
        num_frames=arguments.num_frames,
        frames_per_movie=arguments.frames_per_movie,
        height=height,
        width=width,
    )
    path = datamodule.write_answer(model, arguments.out, split=arguments.split)
    print(f"wrote {path}")
    return path
