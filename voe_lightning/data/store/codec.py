"""How one record becomes the bytes of a shard and back (docs/architecture.md §5): each leaf in
storage order, frames and masks as uint8 temporal deltas, the inconsistent video of a probe as its
difference from the consistent one, every other leaf (camera poses, object states) as it is; the
whole zstd-compressed with this process's compressor."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import zstandard
from tensordict import TensorDict, TensorDictBase

#: zstd level: 3 is ~4x faster to write than 9 for ~5% more bytes on rendered frames.
COMPRESSION_LEVEL = 3


@dataclass(frozen=True)
class Leaf:
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

    def to_json(self) -> dict[str, Any]:
        return {
            "key": list(self.key),
            "dtype": self.dtype,
            "shape": list(self.shape),
            "codec": self.codec,
        }

    @staticmethod
    def from_json(entry: dict[str, Any]) -> Leaf:
        return Leaf(tuple(entry["key"]), entry["dtype"], tuple(entry["shape"]), entry["codec"])


def record_schema(record: TensorDictBase) -> list[Leaf]:
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
            derived.append(Leaf(key, dtype, shape, "minus:" + "/".join(twin)))
        else:
            plain.append(Leaf(key, dtype, shape, "delta_t" if video else "raw"))
    return plain + derived


def _delta_t(array: np.ndarray) -> np.ndarray:
    out = array.copy()
    out[1:] -= array[:-1]  # uint8 wraps around: exact and invertible
    return out


def encode(record: TensorDictBase, schema: Sequence[Leaf]) -> bytes:
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


def decode(payload: bytes, schema: Sequence[Leaf]) -> TensorDict:
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


def zstd_codecs() -> tuple[zstandard.ZstdCompressor, zstandard.ZstdDecompressor]:
    """This process's zstd compressor and decompressor (they must not cross processes)."""
    key = os.getpid()
    if key not in _CODECS:
        _CODECS[key] = (
            zstandard.ZstdCompressor(level=COMPRESSION_LEVEL),
            zstandard.ZstdDecompressor(),
        )
    return _CODECS[key]
