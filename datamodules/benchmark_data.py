"""Shared machinery of the external-benchmark readers (IntPhys, DeepMind Physical Concepts):
frame sampling and resizing, recovering possible/impossible pairs from where two videos first
diverge, packing our clip/probe records, counting skipped input, and a decoded-record cache in
the package's own shard format (``voe_lightning.store``) so epochs never re-decode the source."""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import select
import shutil
import tempfile
import threading
import warnings
import weakref
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from PIL import Image
from scipy.optimize import linear_sum_assignment
from tensordict import TensorDict, TensorDictBase
from torch.utils.data import DataLoader, Dataset
from torchrl.data import Categorical, Composite

from voe_lightning import specs
from voe_lightning.store import (
    CorruptShardError,
    ShardReader,
    check_shard,
    record_loader,
    write_shard,
)

#: Bumped whenever the cached record layout changes, so stale caches are rebuilt.
CACHE_FORMAT = "voe_lightning.benchmark_cache/1"
CACHE_META = "cache.json"


class BenchmarkDataError(ValueError):
    """Malformed benchmark input; the message names the file and what was expected, and
    ``reason`` is a short tag under which ``lenient=True`` loading counts the skipped item."""

    def __init__(self, message: str, reason: str = "bad_input"):
        super().__init__(message)
        self.reason = reason

    def __reduce__(self):  # keep the reason when raised in a DataLoader worker
        return type(self), (str(self), self.reason)


# --- skipped input ------------------------------------------------------------------------------
#: Longest skip line a worker sends: a pipe write of at most PIPE_BUF bytes (with the 4-byte
#: length header) is atomic, so lines from several workers never interleave.
_SKIP_LINE_BYTES = select.PIPE_BUF - 4


class SkipLog:
    """Items skipped under ``lenient=True``, counted per reason; an item skipped again (next
    epoch) counts once. Kept in memory, nothing is written to disk: DataLoader worker processes
    (fork or spawn) send their lines through a pipe that a thread of the owning process reads."""

    def __init__(self) -> None:
        self._owner = os.getpid()
        self._lines: set[str] = set()
        self._lock = threading.Lock()
        self._reader, self._writer = multiprocessing.Pipe(duplex=False)
        threading.Thread(
            target=_read_skips, args=(self._reader, self._lines, self._lock), daemon=True
        ).start()
        weakref.finalize(self, self._writer.close)  # the reading thread then ends

    def __getstate__(self) -> dict:  # a worker gets only the pipe's writing end
        return {"_owner": self._owner, "_writer": self._writer}

    def add(self, reason: str, item: str) -> None:
        line = f"{reason}\t{item}".replace("\n", " ").encode()[:_SKIP_LINE_BYTES]
        if os.getpid() == self._owner:
            with self._lock:
                self._lines.add(line.decode(errors="ignore"))
        else:
            self._writer.send_bytes(line)

    def entries(self) -> list[tuple[str, str]]:
        """Every distinct (reason, item) skipped so far, sorted (workers' lines included: a
        worker sends a line before it hands on its next record)."""
        with self._lock:
            _take_skips(self._reader, self._lines)
            lines = list(self._lines)
        return sorted(tuple(line.split("\t", 1)) for line in lines if "\t" in line)

    def counts(self) -> dict[str, int]:
        return dict(Counter(reason for reason, _ in self.entries()))


def _take_skips(reader: Any, lines: set[str]) -> None:
    """Move the lines waiting in the pipe into ``lines`` (the caller holds the lock)."""
    while reader.poll():
        lines.add(reader.recv_bytes().decode(errors="ignore"))


def _read_skips(reader: Any, lines: set[str], lock: threading.Lock) -> None:
    """Keep the pipe drained, so workers never block on it; ends when every writer closed."""
    try:
        while True:
            reader.poll(None)  # wait without taking, so ``entries`` never waits on this thread
            with lock:
                _take_skips(reader, lines)
    except (EOFError, OSError):
        reader.close()


def merge_counts(*counts: dict[str, int]) -> dict[str, int]:
    total: Counter = Counter()
    for count in counts:
        total.update(count)
    return dict(sorted(total.items()))


# --- frames -------------------------------------------------------------------------------------
def frame_indices(
    available: int, num_frames: int, stride: int | None = None, first: int = 0
) -> np.ndarray:
    """Which of a movie's ``available`` frames make the model's ``num_frames``: every
    ``stride``-th from ``first`` if ``stride`` is given, else spread evenly over the movie."""
    if num_frames < 1:
        raise ValueError(f"num_frames must be at least 1, got {num_frames}")
    if stride is None:
        if num_frames > available - first:
            raise ValueError(
                f"cannot take {num_frames} frames from movies of {available} frames "
                f"starting at frame {first}"
            )
        return np.round(np.linspace(first, available - 1, num_frames)).astype(np.int64)
    if stride < 1:
        raise ValueError(f"frame_stride must be at least 1, got {stride}")
    last = first + stride * (num_frames - 1)
    if first < 0 or last >= available:
        raise ValueError(
            f"{num_frames} frames every {stride} from frame {first} need frame {last}, "
            f"but movies have {available} frames (0 to {available - 1})"
        )
    return first + stride * np.arange(num_frames, dtype=np.int64)


def _resize(images: np.ndarray, height: int, width: int, resample: Image.Resampling) -> np.ndarray:
    """Resize each image of a uint8 stack [T, h, w(, 3)] to [T, height, width(, 3)] with PIL."""
    if images.shape[1:3] == (height, width):
        return np.ascontiguousarray(images)
    return np.stack(
        [np.asarray(Image.fromarray(image).resize((width, height), resample)) for image in images]
    )


def resize_frames(frames: np.ndarray, height: int, width: int) -> np.ndarray:
    """uint8 [T, h, w, 3] -> [T, height, width, 3] with PIL's antialiased bilinear filter."""
    return _resize(frames, height, width, Image.Resampling.BILINEAR)


def resize_masks(masks: np.ndarray, height: int, width: int) -> np.ndarray:
    """uint8 [T, h, w] object ids -> [T, height, width] (nearest: ids must not blend)."""
    return _resize(masks, height, width, Image.Resampling.NEAREST)


@dataclass(frozen=True)
class VideoOptions:
    """How a benchmark's videos become model input (which source frames, what size) and when
    two frames count as different (see ``first_divergence``)."""

    indices: tuple[int, ...]
    height: int
    width: int
    divergence_level: int = 10
    divergence_fraction: float = 0.001

    def resize(self, frames: np.ndarray) -> np.ndarray:
        return resize_frames(frames, self.height, self.width)

    def resize_masks(self, masks: np.ndarray) -> np.ndarray:
        return resize_masks(masks, self.height, self.width)


# --- pairing ------------------------------------------------------------------------------------
def first_divergence(a: np.ndarray, b: np.ndarray, level: int = 10, fraction: float = 0.001) -> int:
    """Index of the first frame where videos ``a`` and ``b`` (uint8 [T, H, W, 3]) differ: more
    than ``fraction`` of its pixels differ by more than ``level`` grey levels in some channel
    (tolerating renderer noise). Returns T when they never do."""
    if a.shape != b.shape:
        raise ValueError(f"videos to compare must have the same shape, got {a.shape} and {b.shape}")
    changed = (np.abs(a.astype(np.int16) - b.astype(np.int16)) > level).any(axis=-1)
    differs = changed.reshape(len(a), -1).mean(axis=1) > fraction
    hits = np.flatnonzero(differs)
    return int(hits[0]) if hits.size else len(a)


def match_pairs(
    possible: Sequence[np.ndarray],
    impossible: Sequence[np.ndarray],
    level: int = 10,
    fraction: float = 0.001,
) -> tuple[list[tuple[int, int, int]], bool]:
    """Pair each possible video with the impossible one it shares the longest prefix with
    (one-to-one, maximizing the summed prefix lengths). Returns ([(possible index, impossible
    index, first diverging frame)], ambiguous) where ``ambiguous`` says another pairing has
    the same total, so the videos alone do not decide it."""
    if len(possible) != len(impossible) or not possible:
        raise ValueError(
            f"pairing needs as many possible as impossible videos, got {len(possible)} and "
            f"{len(impossible)}"
        )
    prefix = np.array(
        [[first_divergence(p, i, level, fraction) for i in impossible] for p in possible]
    )
    rows, columns = linear_sum_assignment(prefix, maximize=True)
    best = prefix[rows, columns].sum()
    ambiguous = False
    if len(possible) == 2:  # the only other assignment swaps the partners
        ambiguous = bool(
            prefix[0, 1] + prefix[1, 0] == best and prefix[0, 0] + prefix[1, 1] == best
        )
    return [(int(r), int(c), int(prefix[r, c])) for r, c in zip(rows, columns)], ambiguous


# --- records ------------------------------------------------------------------------------------
def probe_record(
    consistent: tuple[np.ndarray, np.ndarray],
    inconsistent: tuple[np.ndarray, np.ndarray],
    camera: np.ndarray,
    concept: int,
    variant: int,
    manipulation_frame: int,
    quadruplet_index: int,
    pair_in_quadruplet: int,
) -> TensorDict:
    """A probe record (``specs.probe_spec`` keys) from a matched possible (consistent) and
    impossible (inconsistent) video, each (frames, mask). ``seed`` and ``pair_index`` are
    ``2 * quadruplet_index + pair_in_quadruplet``, so the pairs of one quadruplet can be
    regrouped from ``seed // 2`` (``quadruplet_index``) after evaluation. The manipulated ids are
    unknown for external videos: zeros, which the spec allows."""
    pair_index = 2 * quadruplet_index + pair_in_quadruplet
    return TensorDict(
        {
            "consistent": {
                "frames": torch.from_numpy(np.ascontiguousarray(consistent[0])),
                "mask": torch.from_numpy(np.ascontiguousarray(consistent[1])),
            },
            "inconsistent": {
                "frames": torch.from_numpy(np.ascontiguousarray(inconsistent[0])),
                "mask": torch.from_numpy(np.ascontiguousarray(inconsistent[1])),
            },
            "camera": torch.as_tensor(np.asarray(camera, dtype=np.float32)),
            "concept": torch.tensor(concept, dtype=torch.int64),
            "variant": torch.tensor(variant, dtype=torch.int64),
            "manipulation_frame": torch.tensor(manipulation_frame, dtype=torch.int64),
            "manipulated_ids": torch.zeros(4, dtype=torch.int64),
            "seed": torch.tensor(pair_index, dtype=torch.int64),
            "pair_index": torch.tensor(pair_index, dtype=torch.int64),
            "quadruplet_index": torch.tensor(quadruplet_index, dtype=torch.int64),
        },
        batch_size=[],
    )


def clip_record(
    frames: np.ndarray, mask: np.ndarray, camera: np.ndarray, concept: int, kind: int, seed: int
) -> TensorDict:
    """A clip record (``specs.clip_spec`` keys)."""
    return TensorDict(
        {
            "frames": torch.from_numpy(np.ascontiguousarray(frames)),
            "mask": torch.from_numpy(np.ascontiguousarray(mask)),
            "camera": torch.as_tensor(np.asarray(camera, dtype=np.float32)),
            "concept": torch.tensor(concept, dtype=torch.int64),
            "kind": torch.tensor(kind, dtype=torch.int64),
            "seed": torch.tensor(seed, dtype=torch.int64),
        },
        batch_size=[],
    )


def benchmark_spec(
    base: Composite, num_concepts: int, num_variants: int | None = None
) -> Composite:
    """``base`` (specs.clip_spec or probe_spec) with ``concept`` (and ``variant``) over a
    benchmark's own vocabularies instead of ours."""
    spec = base.clone()
    spec["concept"] = Categorical(num_concepts, shape=(), dtype=torch.int64)
    if num_variants is not None:
        spec["variant"] = Categorical(num_variants, shape=(), dtype=torch.int64)
    return spec


class RecordList(Dataset):
    """Records held in memory as a map-style Dataset."""

    def __init__(self, records: Sequence[TensorDictBase]):
        self.records = list(records)

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, index: int) -> TensorDictBase:
        return self.records[index]


class BenchmarkDataModule(L.LightningDataModule):
    """What the benchmark DataModules share: their record specs (over their own concept and
    variant vocabularies), the counts of skipped input, the loader settings, and the model
    input geometry (``video``): num_frames, height and width as given, or, left None, the
    model's (its ``training_frames`` and ``image_size`` hyperparameters), resolved in ``setup``.
    Subclasses set ``concept_names``/``variant_names`` and ``source_frames`` (frames of every
    source video), save hyperparameters num_frames, height, width, frame_stride, first_frame,
    divergence_level, divergence_fraction, num_workers, and call ``_resolve_video(False)`` at
    the end of ``__init__`` (given values are checked at once) and ``_resolve_video()`` at the
    start of ``setup``."""

    concept_names: tuple[str, ...] = ()
    variant_names: tuple[str, ...] = ()
    source_frames: int

    def __init__(self) -> None:
        super().__init__()
        self._skips: dict[str, SkipLog] = {}
        self._cached_skips: dict[str, dict[str, int]] = {}
        self._video: VideoOptions | None = None

    @property
    def video(self) -> VideoOptions:
        """Which source frames become the model's input, at what size."""
        if self._video is None:
            raise RuntimeError(
                f"{type(self).__name__}: num_frames, height or width is left to the model; call "
                "setup() under a trainer with the model, or give them")
        return self._video

    def _resolve_video(self, required: bool = True) -> None:
        """Build ``video`` from num_frames, height and width, taking those left None from the
        trainer's model; ``required`` (in ``setup``) refuses what neither gives, naming it."""
        h = self.hparams
        given = {"num_frames": h.num_frames, "height": h.height, "width": h.width}
        model = getattr(self.trainer, "lightning_module", None)
        model_hparams = getattr(model, "hparams", {})
        height, width = model_hparams.get("image_size") or (None, None)
        from_model = {"num_frames": model_hparams.get("training_frames"), "height": height,
                      "width": width}
        geometry = {name: from_model[name] if value is None else value
                    for name, value in given.items()}
        unresolved = [name for name, value in geometry.items() if value is None]
        if unresolved and required:
            wanted = {"num_frames": "training_frames", "height": "image_size",
                      "width": "image_size"}
            source = "there is no model" if model is None else (
                "the model's hyperparameters have no "
                + " or ".join(dict.fromkeys(wanted[name] for name in unresolved)))
            raise ValueError(
                f"{type(self).__name__}: {', '.join(unresolved)} not given and {source} to "
                "take them from; give " + ", ".join(f"--data.init_args.{n}" for n in unresolved))
        if not unresolved:
            indices = frame_indices(
                self.source_frames, geometry["num_frames"], h.frame_stride, h.first_frame)
            self._video = VideoOptions(tuple(indices.tolist()), geometry["height"],
                                       geometry["width"], h.divergence_level,
                                       h.divergence_fraction)

    def probe_spec(self) -> Composite:
        v = self.video
        base = specs.probe_spec(len(v.indices), v.height, v.width)
        return benchmark_spec(base, len(self.concept_names), len(self.variant_names))

    def clip_spec(self) -> Composite:
        v = self.video
        return benchmark_spec(
            specs.clip_spec(len(v.indices), v.height, v.width), len(self.concept_names)
        )

    @property
    def skipped(self) -> dict[str, int]:
        """Items left out under ``lenient=True``, per reason (this run's and cached builds')."""
        logs = (log.counts() for log in self._skips.values())
        return merge_counts(*logs, *self._cached_skips.values())

    def _loader(self, dataset: Dataset, batch_size: int, **kwargs) -> DataLoader:
        return record_loader(dataset, batch_size, self.hparams.num_workers, **kwargs)


# --- cache --------------------------------------------------------------------------------------
def fingerprint(settings: dict[str, Any], sources: Iterable[str | os.PathLike]) -> str:
    """A short hash of the decoding settings and the source files' names, sizes and mtimes."""
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode())
    for source in sources:
        stat = os.stat(source)
        digest.update(f"{os.fspath(source)}:{stat.st_size}:{stat.st_mtime_ns};".encode())
    return digest.hexdigest()[:16]


class CachedRecords(Dataset):
    """The records of a finished cache directory: map-style random access over its shards. A
    shard that goes bad while in use raises an OSError naming the cache (the next run's
    ``open_cache`` finds it bad and the DataModule rebuilds it)."""

    def __init__(self, directory: str | os.PathLike, meta: dict[str, Any]):
        self.directory = Path(directory)
        self.meta = meta
        self.readers = [ShardReader(self.directory / name) for name in meta["shards"]]
        self._starts = np.cumsum([0] + list(meta["shard_sizes"]))

    def __len__(self) -> int:
        return int(self._starts[-1])

    def seeds(self) -> np.ndarray:
        """Every record's seed in order, from the shard indexes (no record is decoded)."""
        tables = [reader.index.table["seed"] for reader in self.readers]
        return np.concatenate(tables) if tables else np.zeros(0, np.int64)

    def __getitem__(self, index: int) -> TensorDictBase:
        index = int(index)
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} cached records")
        shard = int(np.searchsorted(self._starts, index, side="right") - 1)
        try:
            return self.readers[shard][index - int(self._starts[shard])]
        except CorruptShardError as error:
            raise OSError(
                f"benchmark cache {self.directory} went bad while in use ({error.path}: "
                f"{error.reason}); the next run finds it bad and rebuilds it from the source "
                "dataset"
            ) from None


#: Entries of every cache's meta file and their JSON types.
_CACHE_META_TYPES = {"shards": list, "shard_sizes": list}


def _cache_problem(directory: Path, required: dict[str, type]) -> tuple[str, dict | None]:
    """What is wrong with the cache at ``directory`` ("" if nothing), and its meta."""
    path = directory / CACHE_META
    try:
        meta = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        return f"{path}: unreadable JSON ({error})", None
    if not isinstance(meta, dict):
        return f"{path}: a JSON {type(meta).__name__}, expected an object", None
    if meta.get("format") != CACHE_FORMAT:
        return "", meta  # an older layout: stale, not bad
    for key, kind in {**_CACHE_META_TYPES, **required}.items():
        if key not in meta:
            return f"{path}: {key} is missing", meta
        if not isinstance(meta[key], kind):
            found = type(meta[key]).__name__
            return f"{path}: {key} is a {found}, expected a {kind.__name__}", meta
    names, sizes = meta["shards"], meta["shard_sizes"]
    named = all(isinstance(name, str) and name == Path(name).name for name in names)
    counted = all(isinstance(size, int) and size >= 0 for size in sizes)
    if not (named and counted and len(names) == len(sizes)):
        return f"{path}: shards and shard_sizes are not a file name and a count per shard", meta
    for name, size in zip(names, sizes):
        try:
            index = check_shard(directory / name)
        except CorruptShardError as error:
            return f"{error.path}: {error.reason}", meta
        if len(index) != size:
            return f"{directory / name}: holds {len(index)} records, {path} says {size}", meta
    return "", meta


def open_cache(
    directory: str | os.PathLike, required: dict[str, type] | None = None
) -> CachedRecords | None:
    """The cache at ``directory`` if it was completely written in the current format and is
    intact: its meta file parses, has the entries of ``required`` (name -> JSON type) and one
    size per shard, and every shard is present with all its checksums. A bad cache warns,
    naming the bad file, and counts as none, so the caller rebuilds it from the source."""
    directory = Path(directory)
    if not (directory / CACHE_META).is_file():
        return None
    problem, meta = _cache_problem(directory, required or {})
    if problem:
        warnings.warn(
            f"ignoring the bad benchmark cache {problem}; rebuilding it from the source dataset",
            stacklevel=2,
        )
        return None
    if meta["format"] != CACHE_FORMAT:
        return None
    return CachedRecords(directory, meta)


def write_cache(
    directory: str | os.PathLike,
    records: Iterable[TensorDictBase],
    meta: dict[str, Any] | None = None,
    shard_size: int = 256,
) -> CachedRecords:
    """Write ``records`` as store shards of ``shard_size`` under ``directory``, then the meta
    file last: a cache without it is incomplete and is rebuilt. Written into a temporary sibling
    and renamed, so a concurrent or interrupted writer never leaves a half cache in place.
    ``meta`` is read after ``records`` is exhausted, so a generator may fill it in (counts of
    skipped input, side tables)."""
    directory = Path(directory)
    directory.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{directory.name}.", dir=directory.parent))
    try:
        names, sizes, buffer = [], [], []

        def flush() -> None:
            name = f"shard-{len(names):05d}.voe"
            write_shard(staging / name, buffer)
            names.append(name)
            sizes.append(len(buffer))
            buffer.clear()

        for record in records:
            buffer.append(record)
            if len(buffer) == shard_size:
                flush()
        if buffer:
            flush()
        full_meta = {"format": CACHE_FORMAT, **(meta or {}), "shards": names, "shard_sizes": sizes}
        (staging / CACHE_META).write_text(json.dumps(full_meta, indent=1, sort_keys=True))
        if directory.exists():  # an older or incomplete cache
            shutil.rmtree(directory)
        os.replace(staging, directory)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return CachedRecords(directory, json.loads((directory / CACHE_META).read_text()))
