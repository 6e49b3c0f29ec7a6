"""The DeepMind Physical Concepts dataset (Piloto et al. 2022) read as our
records, without TensorFlow.

Layout (as released): ``freeform/{train,test}/data.tfrecord-XXXXX-of-YYYYY`` and
``probes/<concept>/data.tfrecord-XXXXX-of-YYYYY``, GZIP-compressed TFRecord files of
``tf.train.Example`` protos. Freeform features: ``image`` (raw uint8 bytes of [15, 64, 64, 3]),
``mask`` (raw uint8 [15, 64, 64]), ``camera_pose`` (float32 [15, 6]). Probe features:
``possible_image`` / ``impossible_image`` (raw uint8 [2, 15, 64, 64, 3]), ``possible_mask`` /
``impossible_mask`` ([2, 15, 64, 64]), ``possible_camera_pose`` / ``impossible_camera_pose``
([2, 15, 6]). The TFRecord framing (little-endian uint64 length, masked CRC32-C of the length,
payload, masked CRC32-C of the payload) is read here so both checksums are verified; the
``tfrecord`` package supplies the Example protobuf and the masked CRC.

Freeform records become our clips (concept ``freeform``); each probe quadruplet (two possible,
two impossible videos) becomes two probe pairs, each possible video matched with the impossible
video it shares the longest prefix with (``manipulation_frame`` = first frame they differ).
The quadruplet is exposed as our stores expose theirs: both pairs carry ``seed =
quadruplet_index = shard * 1_000_000 + record``, and the variant names the half, ``standard``
for the pair of the record's first possible video (A, AB) and ``counterbalanced`` for the
second's (B, BA), so reports test it by ``statistics.quadruplet_test`` (the halves name no
direction of the violation: the release's order).
The camera poses are kept in the dataset's own convention.
"""

from __future__ import annotations

import gzip
import math
import re
import struct
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from google.protobuf.message import DecodeError
from tensordict import TensorDict
from tfrecord import example_pb2
from tfrecord.writer import TFRecordWriter
from torch.utils.data import ConcatDataset, Dataset, IterableDataset, get_worker_info

from voe_lightning import specs
from voe_lightning.benchmarks.reader import (
    BenchmarkDataError,
    FrameSampling,
    SkipLog,
    match_pairs,
)

#: The five probe concepts of the release, in the order of our concept index.
PROBE_CONCEPTS: tuple[str, ...] = (
    "continuity",
    "solidity",
    "object_persistence",
    "unchangeableness",
    "directional_inertia",
)
CONCEPT_NAMES: tuple[str, ...] = PROBE_CONCEPTS + ("freeform",)
VARIANT_NAMES: tuple[str, ...] = specs.QUADRUPLET_VARIANTS
#: What a probe record's seed and variant mean (cached records of another are decoded again):
#: 2, the quadruplet index and the half; 1 was ``2 * quadruplet_index + pair``, variant 0.
RECORD_VERSION = 2
#: Native geometry of every video in the release.
NUM_FRAMES, HEIGHT, WIDTH = 15, 64, 64
#: quadruplet_index = shard * SHARD_STRIDE + record number within the shard.
SHARD_STRIDE = 1_000_000
SHARD_NAME = re.compile(r"^data\.tfrecord-(\d{5})-of-(\d{5})$")
#: The largest record length read: a quadruplet of the release is a few MB; a length field
#: beyond this (a damaged or hostile file) is refused rather than allocated.
MAX_RECORD_BYTES = 256 << 20


# --- TFRecord files ------------------------------------------------------------------------------
def _read_exact(
    stream: gzip.GzipFile, size: int, path: Path, number: int, at_boundary: bool
) -> bytes | None:
    try:
        data = stream.read(size)
    except (EOFError, OSError, zlib.error) as error:  # gzip.BadGzipFile is an OSError
        raise BenchmarkDataError(
            f"{path}: truncated or corrupt GZIP stream in record {number} ({error}); expected a "
            "complete GZIP-compressed TFRecord file",
            "truncated",
        ) from None
    if at_boundary and not data:
        return None
    if len(data) != size:
        raise BenchmarkDataError(
            f"{path}: truncated in record {number}: needed {size} bytes, found {len(data)}",
            "truncated",
        )
    return data


def read_records(
    path: str | Path, skip: Callable[[BenchmarkDataError], None] | None = None
) -> Iterator[bytes]:
    """The payloads of a GZIP-compressed TFRecord file, both CRCs checked. A bad record raises
    a BenchmarkDataError naming the file and record; with ``skip`` it is passed there instead
    and reading goes on with the next record (payload checksum) or stops (broken framing)."""
    path = Path(path)
    masked_crc = TFRecordWriter.masked_crc
    with gzip.open(path, "rb") as stream:
        number = 0
        while True:
            try:
                header = _read_exact(stream, 12, path, number, at_boundary=True)
                if header is None and number == 0:
                    raise BenchmarkDataError(
                        f"{path}: empty ({path.stat().st_size} bytes, no records); expected a "
                        "GZIP-compressed TFRecord file of at least one record",
                        "empty",
                    )
                if header is None:
                    return
                if masked_crc(header[:8]) != header[8:]:
                    raise BenchmarkDataError(
                        f"{path}: record {number}: length checksum mismatch; expected the masked "
                        "CRC32-C of the length (corrupt file or not a TFRecord file)",
                        "bad_crc",
                    )
                (length,) = struct.unpack("<Q", header[:8])
                if length > MAX_RECORD_BYTES:
                    raise BenchmarkDataError(
                        f"{path}: record {number}: length field {length:,} bytes, more than any "
                        f"record of the release (at most {MAX_RECORD_BYTES:,}); a damaged file",
                        "bad_length",
                    )
                body = _read_exact(stream, length + 4, path, number, at_boundary=False)
                assert body is not None  # not at a boundary: all of it, or an error
                if masked_crc(body[:-4]) != body[-4:]:
                    error = BenchmarkDataError(
                        f"{path}: record {number}: payload checksum mismatch; expected the masked "
                        "CRC32-C stored after it",
                        "bad_crc",
                    )
                    if skip is None:
                        raise error
                    skip(error)
                else:
                    yield body[:-4]
            except BenchmarkDataError as error:
                if skip is None:
                    raise
                skip(error)
                return
            number += 1


def shard_files(
    folder: str | Path, skip: Callable[[BenchmarkDataError], None] | None = None
) -> list[Path]:
    """The ``data.tfrecord-XXXXX-of-YYYYY`` files of ``folder`` in shard order; a missing shard
    raises (or, with ``skip``, is reported there)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(
            f"no folder {folder}; expected data.tfrecord-XXXXX-of-YYYYY shards there"
        )
    found = {}
    for path in folder.iterdir():
        match = SHARD_NAME.match(path.name)
        if match:
            found[int(match[1])] = (path, int(match[2]))
    if not found:
        raise FileNotFoundError(f"no data.tfrecord-XXXXX-of-YYYYY shards in {folder}")
    totals = sorted({total for _, total in found.values()})
    if len(totals) > 1:
        raise BenchmarkDataError(
            f"{folder} mixes shards of {totals} files; expected one set", "missing_shard"
        )
    total = totals[0]
    for index in sorted(set(range(total)) - set(found)):
        error = BenchmarkDataError(
            f"missing shard {folder / f'data.tfrecord-{index:05d}-of-{total:05d}'}; expected {total} "
            "shards numbered from 00000",
            "missing_shard",
        )
        if skip is None:
            raise error
        skip(error)
    return [found[index][0] for index in sorted(found) if index < total]


def parse_example(payload: bytes, where: str) -> Any:
    """The feature map of a serialized ``tf.train.Example``."""
    example = example_pb2.Example()
    try:
        example.ParseFromString(payload)
    except DecodeError as error:
        raise BenchmarkDataError(
            f"{where}: not a tf.train.Example ({error})", "bad_record"
        ) from None
    return example.features.feature


def raw_array(features: Any, key: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """A raw-bytes uint8 feature reshaped to ``shape``, its byte count checked."""
    if key not in features:
        raise BenchmarkDataError(
            f"{where}: no feature {key!r}; expected uint8 bytes of {list(shape)}", "bad_record"
        )
    values = features[key].bytes_list.value
    expected = math.prod(shape)
    if len(values) != 1 or len(values[0]) != expected:
        got = f"{len(values[0])} bytes" if len(values) == 1 else f"{len(values)} byte strings"
        raise BenchmarkDataError(
            f"{where}: feature {key!r} holds {got}, expected {expected} bytes (uint8 {list(shape)})",
            "wrong_byte_count",
        )
    return np.frombuffer(values[0], np.uint8).reshape(shape)


def float_array(features: Any, key: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """A float feature reshaped to ``shape``, its length checked."""
    if key not in features:
        raise BenchmarkDataError(
            f"{where}: no feature {key!r}; expected float32 {list(shape)}", "bad_record"
        )
    values = features[key].float_list.value
    if len(values) != math.prod(shape):
        raise BenchmarkDataError(
            f"{where}: feature {key!r} holds {len(values)} floats, expected {math.prod(shape)} "
            f"(float32 {list(shape)})",
            "wrong_byte_count",
        )
    return np.asarray(values, np.float32).reshape(shape)


def decode_freeform(payload: bytes, where: str) -> dict[str, np.ndarray]:
    """image [15, 64, 64, 3], mask [15, 64, 64], camera_pose [15, 6] of a freeform record."""
    features = parse_example(payload, where)
    return {
        "image": raw_array(features, "image", (NUM_FRAMES, HEIGHT, WIDTH, 3), where),
        "mask": raw_array(features, "mask", (NUM_FRAMES, HEIGHT, WIDTH), where),
        "camera_pose": float_array(features, "camera_pose", (NUM_FRAMES, 6), where),
    }


def decode_probe(payload: bytes, where: str) -> dict[str, np.ndarray]:
    """{possible,impossible}_{image [2, 15, 64, 64, 3], mask [2, 15, 64, 64], camera_pose
    [2, 15, 6]} of a probe record."""
    features = parse_example(payload, where)
    result = {}
    for side in ("possible", "impossible"):
        result[f"{side}_image"] = raw_array(
            features, f"{side}_image", (2, NUM_FRAMES, HEIGHT, WIDTH, 3), where
        )
        result[f"{side}_mask"] = raw_array(
            features, f"{side}_mask", (2, NUM_FRAMES, HEIGHT, WIDTH), where
        )
        result[f"{side}_camera_pose"] = float_array(
            features, f"{side}_camera_pose", (2, NUM_FRAMES, 6), where
        )
    return result


# --- records -------------------------------------------------------------------------------------
def freeform_clip(payload: bytes, where: str, video: FrameSampling, seed: int) -> TensorDict:
    row = decode_freeform(payload, where)
    indices = list(video.indices)
    return specs.clip_record(
        video.resize(row["image"][indices]),
        video.resize_masks(row["mask"][indices]),
        row["camera_pose"][indices],
        concept=CONCEPT_NAMES.index("freeform"),
        kind=0,
        seed=seed,
    )


def probe_pairs(
    payload: bytes, where: str, video: FrameSampling, concept: int, quadruplet_index: int
) -> list[TensorDict]:
    """The two probe records of a probe quadruplet, pairs recovered from where they diverge."""
    row = decode_probe(payload, where)
    indices = list(video.indices)
    possible = [row["possible_image"][k][indices] for k in range(2)]
    impossible = [row["impossible_image"][k][indices] for k in range(2)]
    pairs, _ = match_pairs(possible, impossible, video.divergence_level, video.divergence_fraction)
    records = []
    for number, (p, i, divergence) in enumerate(pairs):
        if divergence >= len(indices):
            raise BenchmarkDataError(
                f"{where}: possible video {p} and impossible video {i} do not differ in any of the "
                f"{len(indices)} sampled frames {indices}; sample more frames or lower "
                "divergence_level / divergence_fraction",
                "no_divergence",
            )
        records.append(
            specs.probe_record(
                (video.resize(possible[p]), video.resize_masks(row["possible_mask"][p][indices])),
                (
                    video.resize(impossible[i]),
                    video.resize_masks(row["impossible_mask"][i][indices]),
                ),
                row["possible_camera_pose"][p][indices],
                concept=concept,
                variant=number,
                manipulation_frame=divergence,
                seed=quadruplet_index,
            )
        )
    return records


@dataclass(frozen=True)
class Source:
    """One shard to read: its path, shard number, concept index and record type."""

    path: Path
    shard: int
    concept: int
    kind: str  # "freeform" or "probe"


def _shard_number(path: Path) -> int:
    """The XXXXX of a ``data.tfrecord-XXXXX-of-YYYYY`` file (``shard_files`` lists no other)."""
    match = SHARD_NAME.match(path.name)
    assert match is not None
    return int(match[1])


def part_sources(
    root: str | Path, part: str, skip: Callable[[BenchmarkDataError], None] | None = None
) -> list[Source]:
    """The shards of ``freeform/train`` or ``freeform/test`` (``part`` = train/test) or of a
    concept's probes (``part`` = probes/<concept>); missing shards go to ``skip`` if given."""
    root = Path(root)
    if part.startswith("probes/"):
        concept = part.split("/", 1)[1]
        paths = shard_files(root / "probes" / concept, skip)
        return [Source(p, _shard_number(p), CONCEPT_NAMES.index(concept), "probe") for p in paths]
    paths = shard_files(root / "freeform" / part, skip)
    return [Source(p, _shard_number(p), CONCEPT_NAMES.index("freeform"), "freeform") for p in paths]


def source_records(
    source: Source, video: FrameSampling, lenient: bool, skips: SkipLog, limit: int | None = None
) -> Iterator[TensorDict]:
    """Our records from one shard, in file order (at most ``limit`` source records)."""

    def skip(error: BenchmarkDataError) -> None:
        skips.add(error.reason, str(error))

    for number, payload in enumerate(read_records(source.path, skip if lenient else None)):
        if limit is not None and number >= limit:
            return
        where = f"{source.path}, record {number}"
        index = source.shard * SHARD_STRIDE + number
        try:
            if source.kind == "freeform":
                yield freeform_clip(payload, where, video, seed=index)
            else:
                yield from probe_pairs(payload, where, video, source.concept, index)
        except BenchmarkDataError as error:
            if not lenient:
                raise
            skip(error)


class RecordStream(IterableDataset[TensorDict]):
    """Records decoded on the fly from TFRecord shards. Shards are split over DDP ranks and
    DataLoader workers; with ``shuffle`` the shard order changes every epoch and records pass
    through a ``shuffle_buffer``-sized buffer."""

    def __init__(
        self,
        sources: Sequence[Source],
        video: FrameSampling,
        lenient: bool,
        skips: SkipLog,
        shuffle: bool = False,
        shuffle_buffer: int = 0,
        seed: int = 0,
        limit_per_source: int | None = None,
    ):
        self.sources, self.video, self.lenient, self.skips = list(sources), video, lenient, skips
        self.shuffle, self.shuffle_buffer, self.seed = shuffle, shuffle_buffer, seed
        self.limit_per_source = limit_per_source
        self._epoch = 0

    def __iter__(self) -> Iterator[TensorDict]:
        info = get_worker_info()
        if info is None:
            worker, workers, epoch_seed = 0, 1, self._epoch
            self._epoch += 1
        else:  # a worker's copy: DataLoader draws a new base seed every epoch
            worker, workers, epoch_seed = info.id, info.num_workers, info.seed - info.id
        rank, world = 0, 1
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            rank, world = torch.distributed.get_rank(), torch.distributed.get_world_size()
        sources = list(self.sources)
        if self.shuffle:
            np.random.default_rng([self.seed, epoch_seed]).shuffle(sources)
        mine = sources[rank * workers + worker :: world * workers]
        records: Iterator[TensorDict] = (
            record
            for source in mine
            for record in source_records(
                source, self.video, self.lenient, self.skips, self.limit_per_source
            )
        )
        if self.shuffle and self.shuffle_buffer > 1:
            records = _buffer_shuffle(
                records,
                self.shuffle_buffer,
                np.random.default_rng([self.seed, epoch_seed, worker, rank]),
            )
        yield from records


def _buffer_shuffle(
    records: Iterator[TensorDict], size: int, rng: np.random.Generator
) -> Iterator[TensorDict]:
    buffer: list[TensorDict] = []
    for record in records:
        if len(buffer) < size:
            buffer.append(record)
            continue
        slot = int(rng.integers(size))
        yield buffer[slot]
        buffer[slot] = record
    rng.shuffle(buffer)
    yield from buffer


def chain(datasets: list[Dataset[TensorDict]]) -> Dataset[TensorDict]:
    """Concatenate map-style datasets, or chain iterable ones (one loader over all concepts)."""
    if len(datasets) == 1:
        return datasets[0]
    streams = [d for d in datasets if isinstance(d, IterableDataset)]
    if len(streams) == len(datasets):
        return _ChainedStreams(streams)
    return ConcatDataset(datasets)


class _ChainedStreams(IterableDataset[TensorDict]):
    """Several RecordStreams read one after another; each splits its own shards over workers."""

    def __init__(self, streams: list[IterableDataset[TensorDict]]):
        self.streams = streams

    def __iter__(self) -> Iterator[TensorDict]:
        for stream in self.streams:
            yield from stream
