"""A probe split as WebDataset tar shards, for training and evaluating at scale: one sample per
probe pair, its files named ``<key>.<ext>`` and stored together as the WebDataset convention
asks (``key`` the pair's, ``ProbePair.key``): ``<key>.json`` (concept, variant, seed, labels,
quadruplet and half, the videos' names) and every leaf of the store record as a ``.npy``,
losslessly (``<key>.consistent.frames.npy``, ``<key>.inconsistent.mask.npy``,
``<key>.camera.npy``, ``<key>.consistent.objects.position.npy``, ...). Shards hold whole
groups, so a quadruplet's two pairs are in one shard, next to each other. The tar members have
fixed owners, modes and times, so one store gives byte-identical shards. ``read_webdataset``
reads them back (``webdataset.WebDataset(...).decode()`` reads them too)."""

from __future__ import annotations

import io
import json
import tarfile
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from voe_lightning.data.store import GENERATOR_VERSION
from voe_lightning.export.manifest import ExportFolder, Progress, Written, group_entry
from voe_lightning.export.probes import LABELS, ROLES, ProbeGroup, ProbePair, ProbeSource

SHARD_NAME = "{split}-{index:06d}.tar"
#: Modification time of every tar member (the epoch): no clock in the bytes.
MEMBER_MTIME = 0


def npy_bytes(array: np.ndarray) -> bytes:
    """``array`` as the bytes of a ``.npy`` file (no pickles)."""
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue()


def sample_meta(source: ProbeSource, pair: ProbePair, record: TensorDictBase) -> dict[str, Any]:
    """A sample's ``.json``: what the pair is, its labels and videos, and which store made it."""
    return {
        "key": pair.key,
        "concept": pair.concept,
        "variant": pair.variant,
        "seed": pair.seed,
        "manipulation_frame": int(record["manipulation_frame"]),
        "quadruplet": pair.quadruplet,
        "half": pair.half,
        "videos": {role: pair.video_name(role) for role in ROLES},
        "labels": dict(LABELS),
        "split": source.split,
        "seed_offset": source.seed_offset,
        "generator_version": GENERATOR_VERSION,
    }


def sample_files(meta: dict[str, Any], record: TensorDictBase) -> list[tuple[str, bytes]]:
    """A sample's files, (name, bytes): its ``.json``, then each record leaf's ``.npy``
    (nested keys joined by dots), in name order."""
    key = meta["key"]
    leaves = []
    for name, leaf in record.items(include_nested=True, leaves_only=True):
        path = ".".join(name) if isinstance(name, tuple) else name
        leaves.append((f"{key}.{path}.npy", npy_bytes(leaf.numpy())))
    meta_file = (f"{key}.json", (json.dumps(meta, sort_keys=True) + "\n").encode())
    return [meta_file, *sorted(leaves)]


def add_member(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    """Add a file to ``tar`` with fixed owner, mode and time."""
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode = len(data), MEMBER_MTIME, 0o644
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    tar.addfile(info, io.BytesIO(data))


def shard_groups(groups: Sequence[ProbeGroup], shard_size: int) -> list[list[ProbeGroup]]:
    """``groups`` cut into shards of at most ``shard_size`` pairs, never splitting a group
    (a shard holds one group more than ``shard_size`` allows only when that group is alone)."""
    shards: list[list[ProbeGroup]] = [[]]
    pairs = 0
    for group in groups:
        if shards[-1] and pairs + len(group.pairs) > shard_size:
            shards.append([])
            pairs = 0
        shards[-1].append(group)
        pairs += len(group.pairs)
    return shards


def write_webdataset(
    source: ProbeSource, folder: ExportFolder, bar: Progress, shard_size: int
) -> Written:
    """Write ``source``'s pairs as tar shards ``<split>-NNNNNN.tar`` of at most
    ``shard_size`` pairs each."""
    written = Written(
        layout={
            "shards": SHARD_NAME.format(split=source.split, index=0).replace("000000", "NNNNNN"),
            "shard_size": shard_size,
            "sample": "one probe pair: <key>.json, <key>.<record leaf>.npy",
            "video_location": "<shard>/<key>.<role>: the sample's <key>.<role>.*.npy files",
        },
        encoding={
            "frames": "npy, uint8 [T, H, W, 3], lossless; every record leaf likewise",
            "labels": "<key>.json labels (consistent: possible)",
        },
    )
    for index, groups in enumerate(shard_groups(source.groups, shard_size)):
        shard = SHARD_NAME.format(split=source.split, index=index)
        with tarfile.open(folder.path / shard, "w", format=tarfile.PAX_FORMAT) as tar:
            for group in groups:
                records = source.records(group)
                for pair, record in zip(group.pairs, records):
                    for name, data in sample_files(sample_meta(source, pair, record), record):
                        add_member(tar, name, data)
                locations = [
                    [f"{shard}/{pair.key}.{role}" for role in ROLES] for pair in group.pairs
                ]
                written.groups.append(group_entry(group, records, locations))
                bar.update(2 * len(group.pairs))
        folder.add(shard)
    return written


def _record(leaves: dict[str, np.ndarray]) -> TensorDict:
    """A record from its leaves' dotted names."""
    nested: dict[str, Any] = {}
    for name, array in leaves.items():
        *parents, last = name.split(".")
        level = nested
        for parent in parents:
            level = level.setdefault(parent, {})
        level[last] = torch.from_numpy(array)
    return TensorDict(nested, batch_size=[])


def read_webdataset(shards: Iterable[str | Path]) -> Iterator[tuple[dict[str, Any], TensorDict]]:
    """Each sample of the tar ``shards``, in order: its ``.json`` and its record, rebuilt from
    its ``.npy`` files. A ValueError names a shard whose samples are not stored together."""
    for shard in shards:
        seen: set[str] = set()
        current: str | None = None
        meta: dict[str, Any] = {}
        leaves: dict[str, np.ndarray] = {}
        with tarfile.open(shard) as tar:
            for member in tar:
                key, _, extension = member.name.partition(".")
                if key != current:
                    if current is not None:
                        yield meta, _record(leaves)
                    if key in seen:
                        raise ValueError(f"{shard}: sample {key}'s files are not stored together")
                    seen.add(key)
                    current, meta, leaves = key, {}, {}
                data = tar.extractfile(member)
                if data is None:
                    raise ValueError(f"{shard}: {member.name} is not a file; a sample holds files")
                if extension == "json":
                    meta = json.loads(data.read())
                elif extension.endswith(".npy"):
                    leaves[extension.removesuffix(".npy")] = np.load(io.BytesIO(data.read()))
        if current is not None:
            yield meta, _record(leaves)
