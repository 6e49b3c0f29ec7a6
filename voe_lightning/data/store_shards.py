"""The shard file (docs/architecture.md §5): a header, one zstd blob per record (``store_codec``)
with its CRC32, then an index of offsets, lengths, checksums and seeds with the shard's metadata
and leaf schema, so a DataLoader worker reads one record without the rest. Writing is atomic
(``atomic_write``, which the manifest uses too); reading checks what it reads
(``check_shard``, ``ShardReader``) and names the file in a ``CorruptShardError``."""

from __future__ import annotations

import errno
import glob
import json
import os
import re
import shutil
import socket
import struct
import tempfile
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import zstandard
from tensordict import TensorDict, TensorDictBase

from voe_lightning.data.store_codec import Leaf, decode, encode, record_schema, zstd_codecs

#: Version of the shard format, written into every shard's metadata and the manifest.
FORMAT = "voe_lightning.store/1"

_MAGIC = b"VOESHRD1"
# trailer offset, meta length, record count, trailer crc32, reserved, magic
_FOOTER = struct.Struct("<QIIII8s")
_FOOTER_MAGIC = b"VOEINDEX"
_TABLE_DTYPE = np.dtype([("offset", "<u8"), ("length", "<u4"), ("crc", "<u4"), ("seed", "<i8")])


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
    return write_whole({path: chunks})[Path(path)]


def write_whole(
    files: Mapping[str | os.PathLike, Iterable[bytes] | bytes | str],
) -> dict[Path, int]:
    """Write several files as ``atomic_write`` does one, as a set: every file is staged (its
    temporary file in its own folder, written and fsynced) before any replaces its old
    version, so a write that fails (a full disk) leaves every previous file whole, and the
    error names the file. An empty folder where a file belongs is replaced too (a non-empty
    one is named). Contents are bytes, text (UTF-8) or chunks of bytes; returns the bytes
    written per file."""
    staged: dict[Path, str] = {}
    sizes: dict[Path, int] = {}
    try:
        for name, content in files.items():
            path = Path(name)
            chunks = (
                [content.encode()]
                if isinstance(content, str)
                else [content]
                if isinstance(content, bytes)
                else content
            )
            staged[path], sizes[path] = _stage(path, chunks)
        for path in list(staged):
            try:
                if path.is_dir() and not path.is_symlink() and not any(path.iterdir()):
                    path.rmdir()
                os.replace(staged[path], path)
            except OSError as error:
                raise OSError(
                    error.errno, f"cannot write {path}: {error.strerror or error}", str(path)
                ) from error
            del staged[path]
        return sizes
    finally:
        for temporary in staged.values():
            try:
                os.unlink(temporary)
            except OSError:
                pass


def temporary_prefix(name: str) -> str:
    """``.<name>.<host>.<pid>.``: the prefix of a temporary file or folder of this process
    standing in for ``name`` (``remove_stale`` tells those of a killed process)."""
    return f".{name}.{socket.gethostname()}.{os.getpid()}."


def remove_stale(folder: Path, name: str) -> None:
    """Remove the temporary files and folders (``temporary_prefix``) of ``name`` in ``folder``
    that a process of this host left when it was killed (SIGKILL, power loss) before cleaning
    up: its id no longer runs. Another host's, or a running process's, are left alone."""
    pattern = re.compile(rf"\.{re.escape(name)}\.{re.escape(socket.gethostname())}\.(\d+)\.")
    for path in folder.glob(f".{glob.escape(name)}.*"):
        match = pattern.match(path.name)
        if match and not _running(int(match[1])):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)


def _running(pid: int) -> bool:
    """Whether a process ``pid`` runs on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's
        return True
    return True


def _stage(path: Path, chunks: Iterable[bytes]) -> tuple[str, int]:
    """``chunks`` written and fsynced to a new temporary file beside ``path`` (with ``open``'s
    mode): its name and size. OSErrors name ``path``; the temporary file is gone after one,
    and those a killed writer left beside ``path`` go first (``remove_stale``)."""
    temporary = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale(path.parent, path.name)
        handle, temporary = tempfile.mkstemp(
            prefix=temporary_prefix(path.name), suffix=".tmp", dir=path.parent
        )
        os.fchmod(handle, 0o666 & ~current_umask())
        size = 0
        with os.fdopen(handle, "wb") as file:
            for chunk in chunks:
                _write_bytes(file, chunk)
                size += len(chunk)
            file.flush()
            os.fsync(file.fileno())
        return temporary, size
    except OSError as error:
        if temporary is not None:
            try:
                os.unlink(temporary)
            except OSError:
                pass
        if isinstance(error, CorruptShardError):
            raise
        reason = error.strerror or str(error)
        raise OSError(error.errno, f"cannot write {path}: {reason}", str(path)) from error


def write_shard(
    path: str | os.PathLike, records: Sequence[TensorDictBase], meta: dict[str, Any] | None = None
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
        # What the shard is (concept, split, version) first: a shard copied from elsewhere is
        # named by that, not by its seeds.
        for key, value in (expected_meta or {}).items():
            if index.meta.get(key) != value:
                stored = repr(index.meta[key]) if key in index.meta else "missing"
                raise CorruptShardError(
                    path, f"does not belong here: its {key} is {stored}, expected {value!r}"
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
            raise IndexError(
                f"record {number} out of range for {len(index)} records in {self.path}"
            )
        offset, length, crc, _ = index.table[number].tolist()
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

    def __getstate__(self) -> dict:
        return {"path": self.path, "_fd": None, "_pid": None, "_index": None}

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
