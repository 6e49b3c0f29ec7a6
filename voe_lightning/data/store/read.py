"""Reading a store (docs/architecture.md §3, §5): each concept's split as a map-style Dataset of
TensorDict records that DataLoader workers read lazily, fork and spawn alike (``open_split``),
and the loaders that batch them as every DataModule serves them."""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torch.utils.data import DataLoader, Dataset, Sampler

from voe_lightning import specs
from voe_lightning.data.store.errors import CorruptShardError
from voe_lightning.data.store.layout import check_split_name, shard_counts, shard_path
from voe_lightning.data.store.manifest import read_manifest_or_error, vocabulary
from voe_lightning.data.store.shards import ShardReader

_MAX_OPEN_SHARDS = 32


def open_split(root: str | os.PathLike[str], concept: str, split: str) -> SplitDataset:
    """The records of ``concept``'s ``split`` (train, val, test or generalization) in the store
    at ``root``, as a torch Dataset of TensorDicts (batch them with ``collate_fn=collate``)."""
    specs.check_concept(concept)
    check_split_name(split)
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


class SplitDataset(Dataset[TensorDict]):
    """A concept's split as a map-style Dataset of TensorDict records (``spec`` describes
    them). Safe to hand to DataLoader workers: each process opens shards lazily, keeping at
    most 32 open."""

    def __init__(
        self, root: str | os.PathLike[str], concept: str, split: str, manifest: dict[str, Any]
    ):
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
                    reader.path,
                    f"holds {len(reader)} records, the manifest says {self.shard_sizes[shard]}",
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

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_readers"] = OrderedDict()
        return state

    def __repr__(self) -> str:
        return f"SplitDataset({str(self.root)!r}, {self.concept!r}, {self.split!r}, {len(self)} records)"


def collate(records: Sequence[TensorDictBase]) -> TensorDictBase:
    """DataLoader ``collate_fn`` for store records: stack them to batch_size [B] (torch's
    default collate does not know TensorDicts)."""
    return torch.stack(list(records))


def record_loader(
    dataset: Dataset[TensorDict], batch_size: int, num_workers: int = 0, **kwargs: Any
) -> DataLoader[TensorDict]:
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


def probe_sampler(dataset: Dataset[TensorDict]) -> Sampler[int] | None:
    """Under DDP, each probe pair on exactly one rank, in order (Lightning's default
    DistributedSampler repeats pairs to even out the ranks, which would count them twice in
    the paired test); None (sequential) in a single process."""
    if not (torch.distributed.is_available() and torch.distributed.is_initialized()):
        return None
    # Imported here: generation workers import this module and need no Lightning.
    from lightning.pytorch.overrides.distributed import UnrepeatedDistributedSampler

    return UnrepeatedDistributedSampler(dataset, shuffle=False)
