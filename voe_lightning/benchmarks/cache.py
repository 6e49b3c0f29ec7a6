"""A benchmark's decoded records cached as a store (``voe_lightning.data.store``: ``manifest.json``
and its shards), so epochs never re-decode the source; a cache that is incomplete, stale or
damaged warns and counts as none, and is rebuilt."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from tensordict import TensorDictBase
from torchrl.data import Composite

from voe_lightning.data import store
from voe_lightning.data.store import CorruptShardError, SplitDataset

#: The store concept and split under which a cache keeps its one record set.
CONCEPT, SPLIT = "benchmark", "records"


def fingerprint(settings: dict[str, Any], sources: Iterable[str | os.PathLike[str]]) -> str:
    """A short hash of the decoding settings and the source files' names, sizes and mtimes."""
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode())
    for source in sources:
        stat = os.stat(source)
        digest.update(f"{os.fspath(source)}:{stat.st_size}:{stat.st_mtime_ns};".encode())
    return digest.hexdigest()[:16]


class CachedRecords(SplitDataset):
    """The records of a finished cache, ``meta`` its manifest. A shard that goes bad while in
    use raises an OSError naming the cache (the next run's ``open_cache`` rebuilds it)."""

    def __init__(self, directory: str | os.PathLike[str], manifest: dict[str, Any]):
        super().__init__(directory, CONCEPT, SPLIT, manifest)
        self.meta = manifest

    def seeds(self) -> np.ndarray:
        """Every record's seed in order, from the shard indexes (no record is decoded)."""
        tables = [self._reader(shard).index.table["seed"] for shard in range(len(self.paths))]
        return np.concatenate(tables) if tables else np.zeros(0, np.int64)

    def __getitem__(self, index: int) -> TensorDictBase:
        try:
            return super().__getitem__(index)
        except CorruptShardError as error:
            raise OSError(
                f"benchmark cache {self.root} went bad while in use ({error.path}: "
                f"{error.reason}); the next run finds it bad and rebuilds it from the source "
                "dataset"
            ) from None


def _cache_problem(directory: Path, required: dict[str, type]) -> tuple[str, dict[str, Any] | None]:
    """What is wrong with the cache at ``directory`` ("" if nothing), and its manifest."""
    path = directory / store.MANIFEST_NAME
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as error:
        return f"{path}: unreadable JSON ({error})", None
    if not isinstance(manifest, dict):
        return f"{path}: a JSON {type(manifest).__name__}, expected an object", None
    if manifest.get("format") != store.FORMAT:
        return "", manifest  # an older layout: stale, not bad
    for key, kind in {**store.MANIFEST_KEYS, **required}.items():
        if key not in manifest:
            return f"{path}: {key} is missing", manifest
        if not isinstance(manifest[key], kind):
            found = type(manifest[key]).__name__
            return f"{path}: {key} is a {found}, expected a {kind.__name__}", manifest
    try:
        count = manifest["concepts"][CONCEPT]["splits"][SPLIT]["count"]
        sizes = store.shard_counts(count, manifest["shard_size"])
    except (KeyError, TypeError, ValueError):
        return f"{path}: no record count of {CONCEPT}/{SPLIT} and a positive shard_size", manifest
    for number, size in enumerate(sizes):
        shard = store.shard_path(directory, CONCEPT, SPLIT, number)
        try:
            index = store.check_shard(shard)
        except CorruptShardError as error:
            return f"{error.path}: {error.reason}", manifest
        if len(index) != size:
            return f"{shard}: holds {len(index)} records, {path} says {size}", manifest
    return "", manifest


def open_cache(
    directory: str | os.PathLike[str], required: dict[str, type] | None = None
) -> CachedRecords | None:
    """The cache at ``directory`` if it was completely written in the current format and is
    intact: its manifest parses, has the entries of ``required`` (name -> JSON type), and every
    shard is present with all its checksums. A bad cache warns, naming the bad file, and counts
    as none, so the caller rebuilds it from the source."""
    directory = Path(directory)
    if not (directory / store.MANIFEST_NAME).is_file():
        return None
    problem, manifest = _cache_problem(directory, required or {})
    if problem:
        warnings.warn(
            f"ignoring the bad benchmark cache {problem}; rebuilding it from the source dataset",
            stacklevel=2,
        )
        return None
    assert manifest is not None  # no problem: the manifest was read
    if manifest["format"] != store.FORMAT:
        return None
    return CachedRecords(directory, manifest)


def write_cache(
    directory: str | os.PathLike[str],
    records: Iterable[TensorDictBase],
    spec: Composite,
    meta: dict[str, Any] | None = None,
    shard_size: int = 256,
) -> CachedRecords:
    """Write ``records`` (of ``spec``) as store shards of ``shard_size`` under ``directory``,
    then the manifest last: a cache without it is incomplete and is rebuilt. Written into a
    temporary sibling and renamed, so a concurrent or interrupted writer never leaves a half
    cache in place. ``meta`` joins the manifest once ``records`` is exhausted, so a generator
    may fill it in (counts of skipped input, side tables)."""
    directory = Path(directory)
    directory.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{directory.name}.", dir=directory.parent))
    os.chmod(staging, 0o777 & ~store.current_umask())  # mkdtemp makes it 0700 whatever the umask
    try:
        count, shards, buffer = 0, 0, []
        for record in records:
            buffer.append(record)
            count += 1
            if len(buffer) == shard_size:
                store.write_shard(store.shard_path(staging, CONCEPT, SPLIT, shards), buffer)
                shards, buffer = shards + 1, []
        if buffer:
            store.write_shard(store.shard_path(staging, CONCEPT, SPLIT, shards), buffer)
        record_type = "probe" if "consistent" in spec.keys() else "clip"
        frames = spec["consistent", "frames"] if record_type == "probe" else spec["frames"]
        num_frames, height, width, _ = frames.shape
        manifest = {
            **(meta or {}),
            "format": store.FORMAT,
            "video": {"num_frames": num_frames, "height": height, "width": width},
            "shard_size": shard_size,
            "concepts": {
                CONCEPT: {"splits": {SPLIT: {"record_type": record_type, "count": count}}}
            },
        }
        store.write_manifest(staging, manifest)
        if directory.exists():  # an older or incomplete cache
            shutil.rmtree(directory)
        os.replace(staging, directory)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return CachedRecords(directory, store.read_manifest_or_error(directory))
