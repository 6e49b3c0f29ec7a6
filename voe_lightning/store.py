"""A sharded, compressed, random-access store of clip and probe records
(docs/architecture.md §3).

Layout: ``root/manifest.json`` and ``root/<concept>/<split>/shard-NNNNN.voe``. A shard holds one
zstd-compressed blob per record (frames and masks as uint8 temporal deltas, the inconsistent
video of a probe as its difference from the consistent one, every other leaf, such as camera
poses and object states, as it is), each with a CRC32, followed by an
index of offsets, so a DataLoader worker reads one record without touching the rest. Shards are
written atomically; readers open files lazily in each process (fork and spawn workers alike).
"""

from __future__ import annotations

import errno
import json
import math
import os
import struct
import tempfile
import zlib
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import torch
import zstandard
from filelock import FileLock
from tensordict import TensorDict, TensorDictBase
from torch.utils.data import DataLoader, Dataset, Sampler

from voe_lightning import specs

#: Splits of every concept: training clips, validation and test probes, generalization probes.
SPLITS: tuple[str, ...] = ("train", "val", "test", "generalization")
#: What each split holds.
SPLIT_RECORD_TYPE: dict[str, str] = {
    "train": "clip",
    "val": "probe",
    "test": "probe",
    "generalization": "probe",
}
MANIFEST_NAME = "manifest.json"
SHARD_SUFFIX = ".voe"
FORMAT = "voe_lightning.store/1"
#: zstd level: 3 is ~4x faster to write than 9 for ~5% more bytes on rendered frames.
COMPRESSION_LEVEL = 3

_MAGIC = b"VOESHRD1"
# trailer offset, meta length, record count, trailer crc32, reserved, magic
_FOOTER = struct.Struct("<QIIII8s")
_FOOTER_MAGIC = b"VOEINDEX"
_TABLE_DTYPE = np.dtype([("offset", "<u8"), ("length", "<u4"), ("crc", "<u4"), ("seed", "<i8")])
_MAX_OPEN_SHARDS = 32


class CorruptShardError(OSError):
    """A shard that is missing, truncated or fails its checksums; ``path`` names it."""

    def __init__(self, path: str | os.PathLike, reason: str):
        self.path = Path(path)
        self.reason = reason
        super().__init__(errno.EIO, f"corrupt shard {self.path}: {reason}", str(self.path))

    def __str__(self) -> str:
        return (
            f"corrupt shard {self.path}: {self.reason} (rerun generate with this store's settings, "
            "or the fit/test using it, whose prepare_data regenerates bad shards)"
        )

    def __reduce__(self):  # keep both arguments when sent back from a worker process
        return (type(self), (str(self.path), self.reason))


# --- names and paths ----------------------------------------------------------------------------
def check_split(split: str) -> None:
    """Raise a ValueError listing the valid splits if ``split`` is not one of them."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid splits are: {', '.join(SPLITS)}")


def shard_path(root: str | os.PathLike, concept: str, split: str, index: int) -> Path:
    """Where shard ``index`` of a concept's split lives."""
    return Path(root) / concept / split / f"shard-{index:05d}{SHARD_SUFFIX}"


def shard_counts(count: int, shard_size: int) -> list[int]:
    """Records per shard when ``count`` records are cut into shards of ``shard_size``."""
    if shard_size < 1:
        raise ValueError(f"shard_size must be positive, got {shard_size}")
    full, rest = divmod(count, shard_size)
    return [shard_size] * full + ([rest] if rest else [])


# --- record encoding ----------------------------------------------------------------------------
@dataclass(frozen=True)
class _Leaf:
    """How one tensor of a record is stored: ``codec`` is ``raw``, ``delta_t`` (uint8
    difference from the previous frame) or ``minus:<key>`` (uint8 difference from another
    leaf of the same record, then ``delta_t``)."""

    key: tuple[str, ...]
    dtype: str
    shape: tuple[int, ...]
    codec: str

    @property
    def nbytes(self) -> int:
        return int(np.dtype(self.dtype).itemsize * math.prod(self.shape))

    def to_json(self) -> dict:
        return {"key": list(self.key), "dtype": self.dtype, "shape": list(self.shape), "codec": self.codec}

    @staticmethod
    def from_json(entry: dict) -> "_Leaf":
        return _Leaf(tuple(entry["key"]), entry["dtype"], tuple(entry["shape"]), entry["codec"])


def _schema(record: TensorDictBase) -> list[_Leaf]:
    """The leaves of ``record`` in storage order (a referenced leaf before its referrer)."""
    leaves = {}
    for key, value in record.items(include_nested=True, leaves_only=True):
        key = (key,) if isinstance(key, str) else tuple(key)
        leaves[key] = value
    plain, derived = [], []
    # Widest dtypes first, so every leaf stays aligned inside the decoded buffer.
    for key, value in sorted(leaves.items(), key=lambda item: (-item[1].element_size(), item[0])):
        dtype = str(value.numpy().dtype)
        shape = tuple(value.shape)
        video = dtype == "uint8" and value.ndim >= 3 and shape[0] > 1
        twin = ("consistent",) + key[1:] if key[0] == "inconsistent" else None
        if video and twin in leaves and leaves[twin].shape == value.shape:
            derived.append(_Leaf(key, dtype, shape, "minus:" + "/".join(twin)))
        else:
            plain.append(_Leaf(key, dtype, shape, "delta_t" if video else "raw"))
    return plain + derived


def _delta_t(array: np.ndarray) -> np.ndarray:
    out = array.copy()
    out[1:] -= array[:-1]  # uint8 wraps around: exact and invertible
    return out


def _encode(record: TensorDictBase, schema: Sequence[_Leaf]) -> bytes:
    arrays: dict[tuple[str, ...], np.ndarray] = {}
    parts = []
    for leaf in schema:
        array = record.get(leaf.key).detach().cpu().numpy()
        if str(array.dtype) != leaf.dtype or tuple(array.shape) != leaf.shape:
            raise ValueError(
                f"record leaf {'/'.join(leaf.key)} is {array.dtype}{list(array.shape)}, but this "
                f"shard stores {leaf.dtype}{list(leaf.shape)}"
            )
        arrays[leaf.key] = array
        if leaf.codec.startswith("minus:"):
            array = _delta_t(array - arrays[tuple(leaf.codec[6:].split("/"))])
        elif leaf.codec == "delta_t":
            array = _delta_t(array)
        parts.append(np.ascontiguousarray(array).tobytes())
    return b"".join(parts)


def _decode(payload: bytes, schema: Sequence[_Leaf]) -> TensorDict:
    buffer = bytearray(payload)  # writable, so tensors need no copy
    arrays: dict[tuple[str, ...], np.ndarray] = {}
    record = TensorDict({}, batch_size=[])
    offset = 0
    for leaf in schema:
        array = np.frombuffer(buffer, leaf.dtype, math.prod(leaf.shape), offset).reshape(leaf.shape)
        offset += leaf.nbytes
        if leaf.codec != "raw":
            for t in range(1, len(array)):  # undo delta_t; ~100x faster than np.cumsum on uint8
                array[t] += array[t - 1]
            if leaf.codec.startswith("minus:"):
                array += arrays[tuple(leaf.codec[6:].split("/"))]
        arrays[leaf.key] = array
        record.set(leaf.key, torch.from_numpy(array))
    if offset != len(payload):
        raise ValueError(f"payload holds {len(payload)} bytes, schema {offset}")
    return record


_CODECS: dict[int, tuple[zstandard.ZstdCompressor, zstandard.ZstdDecompressor]] = {}


def _codec() -> tuple[zstandard.ZstdCompressor, zstandard.ZstdDecompressor]:
    """This process's zstd compressor and decompressor (they must not cross processes)."""
    key = os.getpid()
    if key not in _CODECS:
        _CODECS[key] = (
            zstandard.ZstdCompressor(level=COMPRESSION_LEVEL),
            zstandard.ZstdDecompressor(),
        )
    return _CODECS[key]


# --- writing ------------------------------------------------------------------------------------
def _write_bytes(file, data: bytes) -> None:
    file.write(data)


def current_umask() -> int:
    """This process's umask, read without changing it (``os.umask`` would, for every thread)."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write(path: str | os.PathLike, chunks: Iterable[bytes]) -> int:
    """Write ``chunks`` to ``path`` atomically (temporary file in the same folder, fsync,
    rename); returns the bytes written. The file gets the mode ``open`` would give it (0666
    less the umask; ``mkstemp`` alone makes it 0600, unreadable to a lab's other users).
    OSErrors (no space, no permission) name ``path``."""
    path = Path(path)
    temporary = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        os.fchmod(handle, 0o666 & ~current_umask())
        size = 0
        with os.fdopen(handle, "wb") as file:
            for chunk in chunks:
                _write_bytes(file, chunk)
                size += len(chunk)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
        temporary = None
        return size
    except OSError as error:
        if isinstance(error, CorruptShardError):
            raise
        reason = error.strerror or str(error)
        raise OSError(error.errno, f"cannot write {path}: {reason}", str(path)) from error
    finally:
        if temporary is not None:
            try:
                os.unlink(temporary)
            except OSError:
                pass


def write_shard(
    path: str | os.PathLike, records: Sequence[TensorDictBase], meta: dict[str, Any] | None = None
) -> int:
    """Write ``records`` (all clips or all probes, same shapes) as one shard at ``path``,
    atomically; ``meta`` (JSON-able) is kept in the shard's index. Returns the file size."""
    if not records:
        raise ValueError(f"a shard needs at least one record ({path})")
    schema = _schema(records[0])
    compressor = _codec()[0]
    table = np.zeros(len(records), _TABLE_DTYPE)
    blobs = []
    offset = len(_MAGIC)
    for index, record in enumerate(records):
        blob = compressor.compress(_encode(record, schema))
        table[index] = (offset, len(blob), zlib.crc32(blob), int(record.get("seed")))
        blobs.append(blob)
        offset += len(blob)
    meta_bytes = json.dumps(
        {"format": FORMAT, **(meta or {}), "schema": [leaf.to_json() for leaf in schema]},
        sort_keys=True,
    ).encode()
    trailer = meta_bytes + table.tobytes()
    footer = _FOOTER.pack(offset, len(meta_bytes), len(records), zlib.crc32(trailer), 0, _FOOTER_MAGIC)
    return atomic_write(path, [_MAGIC, *blobs, trailer, footer])


# --- reading ------------------------------------------------------------------------------------
@dataclass
class ShardIndex:
    """A shard's metadata, leaf schema and per-record offsets, lengths, checksums and seeds."""

    path: Path
    meta: dict[str, Any]
    schema: list[_Leaf]
    table: np.ndarray

    def __len__(self) -> int:
        return len(self.table)

    @property
    def seeds(self) -> list[int]:
        return self.table["seed"].tolist()

    @property
    def layout(self) -> dict[str, tuple[str, tuple[int, ...]]]:
        """Per record leaf ("a/b" key): its dtype and shape, as :func:`spec_layout` gives them."""
        return {"/".join(leaf.key): (leaf.dtype, leaf.shape) for leaf in self.schema}


def spec_layout(spec) -> dict[str, tuple[str, tuple[int, ...]]]:
    """Per leaf of a record spec ("a/b" key): the numpy dtype name and shape a shard stores."""
    layout = {}
    for key, leaf in spec.items(include_nested=True, leaves_only=True):
        key = key if isinstance(key, str) else "/".join(key)
        layout[key] = (str(torch.empty((), dtype=leaf.dtype).numpy().dtype), tuple(leaf.shape))
    return layout


def _read_index(fd: int, path: Path) -> ShardIndex:
    size = os.fstat(fd).st_size
    if size < len(_MAGIC) + _FOOTER.size:
        raise CorruptShardError(path, f"truncated ({size} bytes)")
    if os.pread(fd, len(_MAGIC), 0) != _MAGIC:
        raise CorruptShardError(path, "not a voe_lightning shard (bad header)")
    trailer_offset, meta_length, count, trailer_crc, _, magic = _FOOTER.unpack(
        os.pread(fd, _FOOTER.size, size - _FOOTER.size)
    )
    trailer_length = size - _FOOTER.size - trailer_offset
    if magic != _FOOTER_MAGIC or trailer_length != meta_length + count * _TABLE_DTYPE.itemsize:
        raise CorruptShardError(path, "truncated or damaged index")
    trailer = os.pread(fd, trailer_length, trailer_offset)
    if zlib.crc32(trailer) != trailer_crc:
        raise CorruptShardError(path, "index checksum mismatch")
    try:
        meta = json.loads(trailer[:meta_length])
        schema = [_Leaf.from_json(entry) for entry in meta.pop("schema")]
    except (ValueError, KeyError) as error:
        raise CorruptShardError(path, f"unreadable index ({error})") from error
    table = np.frombuffer(trailer, _TABLE_DTYPE, count, meta_length)
    ends = table["offset"].astype(np.int64) + table["length"]
    if count and (table["offset"].min() < len(_MAGIC) or ends.max() > trailer_offset):
        raise CorruptShardError(path, "record offsets outside the file")
    return ShardIndex(path, meta, schema, table)


def _open(path: Path) -> int:
    try:
        return os.open(path, os.O_RDONLY)
    except FileNotFoundError as error:
        raise CorruptShardError(path, "missing") from error


def read_index(path: str | os.PathLike) -> ShardIndex:
    """Read and check a shard's index (cheap: does not read the records)."""
    path = Path(path)
    fd = _open(path)
    try:
        return _read_index(fd, path)
    finally:
        os.close(fd)


def check_shard(
    path: str | os.PathLike,
    expected_seeds: Sequence[int] | None = None,
    full: bool = True,
    expected_meta: dict[str, Any] | None = None,
    expected_layout: dict[str, tuple[str, tuple[int, ...]]] | None = None,
) -> ShardIndex:
    """Raise CorruptShardError naming ``path`` and the first difference unless the shard is
    complete and belongs where it lies: its index is intact, it holds ``expected_seeds``, its
    metadata has the values of ``expected_meta`` and its records the leaves, dtypes and shapes
    of ``expected_layout`` (each if given) and, when ``full``, every record's checksum matches.
    Returns its index."""
    path = Path(path)
    fd = _open(path)
    try:
        index = _read_index(fd, path)
        if expected_seeds is not None and index.seeds != [int(s) for s in expected_seeds]:
            raise CorruptShardError(
                path, f"holds {len(index)} records with other seeds than the {len(expected_seeds)} planned"
            )
        for key, value in (expected_meta or {}).items():
            if index.meta.get(key) != value:
                stored = repr(index.meta[key]) if key in index.meta else "missing"
                raise CorruptShardError(path, f"does not belong here: its {key} is {stored}, expected {value!r}")
        if expected_layout is not None and index.layout != expected_layout:
            stored, expected = index.layout, expected_layout
            first = sorted(k for k in set(stored) | set(expected) if stored.get(k) != expected.get(k))[0]
            raise CorruptShardError(
                path,
                f"does not belong here: its records' {first} is {_describe_leaf(stored.get(first))}, "
                f"expected {_describe_leaf(expected.get(first))}",
            )
        if full and len(index):
            start = int(index.table["offset"].min())
            data = os.pread(fd, int(index.table["offset"][-1] + index.table["length"][-1]) - start, start)
            for number, (offset, length, crc, _) in enumerate(index.table.tolist()):
                if zlib.crc32(data[offset - start : offset - start + length]) != crc:
                    raise CorruptShardError(path, f"record {number} checksum mismatch")
        return index
    finally:
        os.close(fd)


def _describe_leaf(leaf: tuple[str, tuple[int, ...]] | None) -> str:
    return "missing" if leaf is None else f"{leaf[0]}{list(leaf[1])}"


class ShardReader:
    """Random access to one shard's records; the file is opened on first use in each process."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._fd: int | None = None
        self._pid: int | None = None
        self._index: ShardIndex | None = None

    def _ensure_open(self) -> ShardIndex:
        if self._pid != os.getpid():  # first use, or a forked DataLoader worker
            self._fd, self._pid = _open(self.path), os.getpid()
            self._index = _read_index(self._fd, self.path)
        return self._index

    @property
    def index(self) -> ShardIndex:
        return self._ensure_open()

    def __len__(self) -> int:
        return len(self._ensure_open())

    def __getitem__(self, number: int) -> TensorDict:
        index = self._ensure_open()
        if not 0 <= number < len(index):
            raise IndexError(f"record {number} out of range for {len(index)} records in {self.path}")
        offset, length, crc, _ = index.table[number].tolist()
        blob = os.pread(self._fd, length, offset)
        if len(blob) != length or zlib.crc32(blob) != crc:
            raise CorruptShardError(self.path, f"record {number} checksum mismatch")
        try:
            payload = _codec()[1].decompress(blob)
            return _decode(payload, index.schema)
        except (zstandard.ZstdError, ValueError) as error:
            raise CorruptShardError(self.path, f"record {number} undecodable ({error})") from error

    def close(self) -> None:
        if self._fd is not None and self._pid == os.getpid():
            os.close(self._fd)
        self._fd = self._pid = self._index = None

    def __getstate__(self) -> dict:
        return {"path": self.path, "_fd": None, "_pid": None, "_index": None}

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass


class SplitDataset(Dataset):
    """A concept's split as a map-style Dataset of TensorDict records (``spec`` describes
    them). Safe to hand to DataLoader workers: each process opens shards lazily, keeping at
    most 32 open."""

    def __init__(self, root: str | os.PathLike, concept: str, split: str, manifest: dict):
        self.root, self.concept, self.split = Path(root), concept, split
        entry = manifest["concepts"][concept]["splits"][split]
        self.record_type = entry["record_type"]
        video = manifest["video"]
        make_spec = specs.clip_spec if self.record_type == "clip" else specs.probe_spec
        self.spec = make_spec(video["num_frames"], video["height"], video["width"])
        self.shard_sizes = shard_counts(entry["count"], manifest["shard_size"])
        self.paths = [shard_path(root, concept, split, i) for i in range(len(self.shard_sizes))]
        self._starts = np.cumsum([0] + self.shard_sizes)
        self._shard_size = manifest["shard_size"]
        self._readers: OrderedDict[int, ShardReader] = OrderedDict()

    def __len__(self) -> int:
        return int(self._starts[-1])

    def _reader(self, shard: int) -> ShardReader:
        reader = self._readers.get(shard)
        if reader is None:
            reader = ShardReader(self.paths[shard])
            if len(reader) != self.shard_sizes[shard]:
                raise CorruptShardError(
                    reader.path, f"holds {len(reader)} records, the manifest says {self.shard_sizes[shard]}"
                )
            self._readers[shard] = reader
            while len(self._readers) > _MAX_OPEN_SHARDS:
                self._readers.popitem(last=False)[1].close()
        else:
            self._readers.move_to_end(shard)
        return reader

    def __getitem__(self, index: int) -> TensorDict:
        index = int(index)
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} records of {self}")
        shard = index // self._shard_size
        return self._reader(shard)[index - int(self._starts[shard])]

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_readers"] = OrderedDict()
        return state

    def __repr__(self) -> str:
        return f"SplitDataset({str(self.root)!r}, {self.concept!r}, {self.split!r}, {len(self)} records)"


def collate(records: Sequence[TensorDictBase]) -> TensorDictBase:
    """DataLoader ``collate_fn`` for store records: stack them to batch_size [B] (torch's
    default collate does not know TensorDicts)."""
    return torch.stack(list(records))


def record_loader(dataset: Dataset, batch_size: int, num_workers: int = 0, **kwargs) -> DataLoader:
    """A DataLoader of TensorDict record batches, as every DataModule serves them. Workers are
    persistent: torchrl makes multiprocessing spawn, and a spawned worker starts slowly."""
    return DataLoader(
        dataset,
        batch_size=batch_size,
        num_workers=num_workers,
        collate_fn=collate,
        persistent_workers=num_workers > 0,
        **kwargs,
    )


def probe_sampler(dataset: Dataset) -> Sampler | None:
    """Under DDP, each probe pair on exactly one rank, in order (Lightning's default
    DistributedSampler repeats pairs to even out the ranks, which would count them twice in
    the paired test); None (sequential) in a single process."""
    if not (torch.distributed.is_available() and torch.distributed.is_initialized()):
        return None
    # Imported here: generation workers import this module and need no Lightning.
    from lightning.pytorch.overrides.distributed import UnrepeatedDistributedSampler

    return UnrepeatedDistributedSampler(dataset, shuffle=False)


# --- manifest -----------------------------------------------------------------------------------
class ManifestError(ValueError):
    """A manifest that is unreadable or not a store's manifest; the message names the file."""


#: Top-level manifest entries every reader relies on, and their JSON types.
MANIFEST_KEYS = {"video": dict, "shard_size": int, "concepts": dict}


def read_manifest(root: str | os.PathLike) -> dict | None:
    """The root's manifest, or None if there is none yet. Raises ManifestError naming the
    file when it is truncated, not JSON, or JSON of another shape."""
    path = Path(root) / MANIFEST_NAME
    fix = "delete it, or regenerate with generate --overwrite"
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (ValueError, UnicodeDecodeError) as error:
        raise ManifestError(f"unreadable manifest {path} (truncated?): {error}; {fix}") from error
    if not isinstance(manifest, dict):
        raise ManifestError(
            f"{path} holds a JSON {type(manifest).__name__ if manifest is not None else 'null'}, "
            f"not a voe_lightning manifest (an object); {fix}"
        )
    wrong = [
        f"{key} (missing)" if key not in manifest else f"{key} (a {type(manifest[key]).__name__})"
        for key, kind in MANIFEST_KEYS.items()
        if not isinstance(manifest.get(key), kind)
    ]
    if wrong:
        expected = ", ".join(f"{key}: {kind.__name__}" for key, kind in MANIFEST_KEYS.items())
        raise ManifestError(f"{path} is not a voe_lightning manifest: bad {', '.join(wrong)}; expected {expected}; {fix}")
    return manifest


def manifest_lock(root: str | os.PathLike) -> FileLock:
    """The lock a writer holds from reading the root's manifest to writing it back, so two
    ``generate`` runs on one root (say, for two concepts) merge their entries instead of the
    last writer's replacing the other's."""
    Path(root).mkdir(parents=True, exist_ok=True)
    return FileLock(Path(root) / f".{MANIFEST_NAME}.lock")


def write_manifest(root: str | os.PathLike, manifest: dict) -> None:
    """Write the root's manifest atomically."""
    text = json.dumps(manifest, indent=2, sort_keys=True) + "\n"
    atomic_write(Path(root) / MANIFEST_NAME, [text.encode()])


def read_manifest_or_error(root: str | os.PathLike) -> dict:
    """The root's manifest; a FileNotFoundError naming the command that makes one if there is
    none."""
    manifest = read_manifest(root)
    if manifest is None:
        raise FileNotFoundError(
            f"no dataset at {root}: {Path(root) / MANIFEST_NAME} is missing "
            f"(create one with `python -m voe_lightning generate --root {root}`)"
        )
    return manifest


def vocabulary() -> dict[str, list[str]]:
    """The names that records' ``concept``, ``kind`` and ``variant`` indices decode to."""
    return {
        "concepts": list(specs.CONCEPTS),
        "clip_kinds": list(specs.CLIP_KINDS),
        "variants": list(specs.VARIANTS),
    }


def open_split(root: str | os.PathLike, concept: str, split: str) -> SplitDataset:
    """The records of ``concept``'s ``split`` (train, val, test or generalization) in the store
    at ``root``, as a torch Dataset of TensorDicts (batch them with ``collate_fn=collate``)."""
    specs.check_concept(concept)
    check_split(split)
    manifest = read_manifest_or_error(root)
    if manifest.get("vocabulary", vocabulary()) != vocabulary():
        raise ValueError(
            f"the store at {root} was written by voe_lightning {manifest.get('package_version')} "
            "with other concept/kind/variant names, so its indices would decode wrongly; "
            "regenerate it (generate --overwrite)"
        )
    stored = manifest["concepts"]
    if concept not in stored:
        raise ValueError(
            f"concept {concept!r} was not generated in {root}; it holds: {', '.join(stored) or 'none'}"
        )
    return SplitDataset(root, concept, split, manifest)
