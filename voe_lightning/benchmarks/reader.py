"""What the benchmark readers share: errors, text read as UTF-8, skipped-input counts, frame
sampling and resizing, and recovering possible/impossible pairs from where two videos first
diverge."""

from __future__ import annotations

import multiprocessing
import os
import select
import threading
import weakref
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image
from scipy.optimize import linear_sum_assignment
from tensordict import TensorDict
from torch.utils.data import DataLoader, Dataset
from torchrl.data import Categorical, Composite


class BenchmarkDataError(ValueError):
    """Malformed benchmark input; the message names the file and what was expected, and
    ``reason`` is a short tag under which ``lenient=True`` loading counts the skipped item."""

    def __init__(self, message: str, reason: str = "bad_input"):
        super().__init__(message)
        self.reason = reason

    def __reduce__(self) -> tuple[type[BenchmarkDataError], tuple[str, str]]:
        # keep the reason when raised in a DataLoader worker
        return type(self), (str(self), self.reason)


def read_text(path: Path, reason: str = "bad_input", hint: str = "save it as UTF-8") -> str:
    """A benchmark's text file (metadata.csv, status.json, answer.txt) as UTF-8, without the
    byte-order mark a spreadsheet may write: never the locale's encoding, which would read a
    latin-1 file as other characters in silence. Undecodable bytes are a BenchmarkDataError
    (under ``reason``) naming the file, the line and the byte (Python's error names neither
    file nor line); ``hint`` says what to do."""
    data = Path(path).read_bytes()
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        line = data[: error.start].count(b"\n") + 1
        raise BenchmarkDataError(
            f"{path} is not UTF-8 text: line {line} holds the byte "
            f"0x{data[error.start]:02x}, which UTF-8 cannot decode ({error.reason}); {hint}",
            reason,
        ) from None


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

    def __getstate__(self) -> dict[str, Any]:  # a worker gets only the pipe's writing end
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
        split = (line.split("\t", 1) for line in lines if "\t" in line)
        return sorted((reason, item) for reason, item in split)

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
    total: Counter[str] = Counter()
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
class FrameSampling:
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


class RecordList(Dataset[TensorDict]):
    """Records held in memory as a map-style Dataset."""

    def __init__(self, records: Sequence[TensorDict]):
        self.records = list(records)

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, index: int) -> TensorDict:
        return self.records[index]


def _identity(item: Any) -> Any:
    return item


def worker_loader(dataset: Dataset[Any], num_workers: int) -> DataLoader[Any]:
    """``dataset``'s items one by one, as they are (no batching, no collation), decoded by
    ``num_workers`` worker processes: how the readers fill a cache."""
    return DataLoader(dataset, batch_size=None, num_workers=num_workers, collate_fn=_identity)
