"""The shard file (docs/architecture.md §5): a header, one zstd blob per record (``codec``) with
its CRC32, then an index of offsets, lengths, checksums and seeds with the shard's metadata and
leaf schema, so a DataLoader worker reads one record without the rest. Written whole
(``files.atomic_write``); reading checks what it reads (``check_shard``, ``ShardReader``) and
names the file in a ``CorruptShardError``."""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import zstandard
from tensordict import TensorDict, TensorDictBase

from voe_lightning.data.store.codec import Leaf, decode, encode, record_schema, zstd_codecs
from voe_lightning.data.store.errors import CorruptShardError
from voe_lightning.data.store.files import atomic_write

if TYPE_CHECKING:
    from torchrl.data import Composite


#: Version of the shard format, written into every shard's metadata and the manifest.
FORMAT = "voe_lightning.store/1"
_MAGIC = b"VOESHRD1"

# trailer offset, meta length, record count, trailer crc32, reserved, magic
_FOOTER = struct.Struct("<QIIII8s")
_FOOTER_MAGIC = b"VOEINDEX"
_TABLE_DTYPE = np.dtype([("offset", "<u8"), ("length", "<u4"), ("crc", "<u4"), ("seed", "<i8")])


# --- writing ------------------------------------------------------------------------------------
def write_shard(
    path: str | os.PathLike[str],
    records: Sequence[TensorDictBase],
    meta: dict[str, Any] | None = None,
) -> int:
    """Write ``records`` (all clips or all probes, same shapes) as one shard at ``path``,
    atomically; ``meta`` (JSON-able) is kept in the shard's index. Returns the file size."""
    if not records:
        raise ValueError(f"a shard needs at least one record ({path})")
    schema = record_schema(records[0])
    compressor = zstd_codecs()[0]
    table = np.zeros(len(records), _TABLE_DTYPE)
    blobs = []
    offset = len(_MAGIC)
    for index, record in enumerate(records):
        blob = compressor.compress(encode(record, schema))
        table[index] = (offset, len(blob), zlib.crc32(blob), int(record.get("seed")))
        blobs.append(blob)
        offset += len(blob)
    meta_bytes = json.dumps(
        {"format": FORMAT, **(meta or {}), "schema": [leaf.to_json() for leaf in schema]},
        sort_keys=True,
    ).encode()
    trailer = meta_bytes + table.tobytes()
    footer = _FOOTER.pack(
        offset, len(meta_bytes), len(records), zlib.crc32(trailer), 0, _FOOTER_MAGIC
    )
    return atomic_write(path, [_MAGIC, *blobs, trailer, footer])


# --- reading ------------------------------------------------------------------------------------
@dataclass
class ShardIndex:
    """A shard's metadata, leaf schema and per-record offsets, lengths, checksums and seeds."""

    path: Path
    meta: dict[str, Any]
    schema: list[Leaf]
    table: np.ndarray

    def __len__(self) -> int:
        return len(self.table)

    @property
    def seeds(self) -> list[int]:
        seeds: list[int] = self.table["seed"].tolist()
        return seeds

    @property
    def layout(self) -> dict[str, tuple[str, tuple[int, ...]]]:
        """Per record leaf ("a/b" key): its dtype and shape, as :func:`spec_layout` gives them."""
        return {"/".join(leaf.key): (leaf.dtype, leaf.shape) for leaf in self.schema}


def spec_layout(spec: Composite) -> dict[str, tuple[str, tuple[int, ...]]]:
    """Per leaf of a record spec ("a/b" key): the numpy dtype name and shape a shard stores."""
    layout: dict[str, tuple[str, tuple[int, ...]]] = {}
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
        schema = [Leaf.from_json(entry) for entry in meta.pop("schema")]
    except (ValueError, KeyError) as error:
        raise CorruptShardError(path, f"unreadable index ({error})") from error
    table = np.frombuffer(trailer, _TABLE_DTYPE, count, meta_length)
    ends = table["offset"].astype(np.int64) + table["length"]
    if count and (table["offset"].min() < len(_MAGIC) or ends.max() > trailer_offset):
        raise CorruptShardError(path, "record offsets outside the file")
    return ShardIndex(path, meta, schema, table)


def _open(path: Path) -> int:
    if path.is_dir():
        raise CorruptShardError(path, "a folder, not a shard file")
    try:
        return os.open(path, os.O_RDONLY)
    except FileNotFoundError as error:
        raise CorruptShardError(path, "missing") from error


def read_index(path: str | os.PathLike[str]) -> ShardIndex:
    """Read and check a shard's index (cheap: does not read the records)."""
    path = Path(path)
    fd = _open(path)
    try:
        return _read_index(fd, path)
    finally:
        os.close(fd)


def check_shard(
    path: str | os.PathLike[str],
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
        # What the shard is (concept, split, version) first: a shard copied from elsewhere is
        # named by that, not by its seeds.
        for key, value in (expected_meta or {}).items():
            if index.meta.get(key) != value:
                found = repr(index.meta[key]) if key in index.meta else "missing"
                raise CorruptShardError(
                    path, f"does not belong here: its {key} is {found}, expected {value!r}"
                )
        if expected_seeds is not None and index.seeds != [int(s) for s in expected_seeds]:
            raise CorruptShardError(
                path,
                f"holds {len(index)} records with other seeds than the {len(expected_seeds)} planned",
            )
        if expected_layout is not None and index.layout != expected_layout:
            stored, expected = index.layout, expected_layout
            first = sorted(
                k for k in set(stored) | set(expected) if stored.get(k) != expected.get(k)
            )[0]
            raise CorruptShardError(
                path,
                f"does not belong here: its records' {first} is {_describe_leaf(stored.get(first))}, "
                f"expected {_describe_leaf(expected.get(first))}",
            )
        if full and len(index):
            start = int(index.table["offset"].min())
            data = os.pread(
                fd, int(index.table["offset"][-1] + index.table["length"][-1]) - start, start
            )
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

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        self._fd: int | None = None
        self._pid: int | None = None
        self._index: ShardIndex | None = None

    def _ensure_open(self) -> ShardIndex:
        if self._pid != os.getpid():  # first use, or a forked DataLoader worker
            self._fd, self._pid = _open(self.path), os.getpid()
            self._index = _read_index(self._fd, self.path)
        assert self._index is not None  # read on first use in this process
        return self._index

    @property
    def index(self) -> ShardIndex:
        return self._ensure_open()

    def __len__(self) -> int:
        return len(self._ensure_open())

    def __getitem__(self, number: int) -> TensorDict:
        index = self._ensure_open()
        if not 0 <= number < len(index):
            raise IndexError(
                f"record {number} out of range for {len(index)} records in {self.path}"
            )
        offset, length, crc, _ = index.table[number].tolist()
        assert self._fd is not None  # opened by _ensure_open
        blob = os.pread(self._fd, length, offset)
        if len(blob) != length or zlib.crc32(blob) != crc:
            raise CorruptShardError(self.path, f"record {number} checksum mismatch")
        try:
            payload = zstd_codecs()[1].decompress(blob)
            return decode(payload, index.schema)
        except (zstandard.ZstdError, ValueError) as error:
            raise CorruptShardError(self.path, f"record {number} undecodable ({error})") from error

    def close(self) -> None:
        if self._fd is not None and self._pid == os.getpid():
            os.close(self._fd)
        self._fd = self._pid = self._index = None

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "_fd": None, "_pid": None, "_index": None}

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
