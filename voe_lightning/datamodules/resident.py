"""Training batches gathered from clips held whole in memory (on the training device, or on
the host), so that at thousands of clips a second loading never waits: each record decoded
once, one gather a batch, no worker processes. Only the fields a model reads are kept: the
frames for a model trained from pixels (the VRNN-LRU; the paper-scale set, about 184 GB at 15
frames of 64x64, does not fit one GPU), the objects' states and the camera for the state
learner, whose batches then never decode a frame; for its mask and RGB-D rungs,
``mask_features``: what each clip's mask and frames show of each id (``masks.per_id``), with
its ``depth`` measures where the records hold them, measured once here instead of every batch,
and no mask, frame or depth held."""

from __future__ import annotations

from collections.abc import Iterator, Sequence, Sized
from typing import Protocol, cast

import torch
from tensordict import TensorDict, TensorDictBase
from torch.utils.data import Dataset
from tqdm import tqdm

from voe_lightning.data.store import record_loader
from voe_lightning.model.object_state.masks import per_id

#: A field no record holds, made of two it does: ``per_id``'s measures of the mask and frames
#: (and of the ``depth``, where the records hold it).
MASK_FEATURES = "mask_features"


def _check_fits(needed: int, clips: int, device: torch.device) -> None:
    """Refuse, naming the sizes, a set that would not fit a GPU's free memory."""
    if device.type != "cuda":
        return
    free, _ = torch.cuda.mem_get_info(device)
    if needed > 0.8 * free:
        raise MemoryError(
            f"the {clips:,} training clips need {needed / 2**30:.1f} GiB on {device}, which has "
            f"{free / 2**30:.1f} GiB free; set train_on_device: false (worker processes load "
            "them) or train on fewer clips"
        )


class SizedSampler(Protocol):
    """A sampler that knows its length, as ``ResidentBatches`` counts its batches."""

    def __iter__(self) -> Iterator[int]: ...

    def __len__(self) -> int: ...


def resident_records(
    dataset: Dataset[TensorDict], fields: Sequence[str], device: torch.device, num_workers: int = 0
) -> TensorDict:
    """Every record's ``fields`` as one TensorDict [N] on ``device``, in dataset order; refused,
    naming the sizes, when it would not fit the device's free memory. An unknown field is
    refused, naming the fields a record has."""
    first = dataset[0]
    measured = MASK_FEATURES in fields
    stored = [name for name in fields if name != MASK_FEATURES]
    missing = [
        name
        for name in stored + (["mask", "frames"] if measured else [])
        if name not in first.keys()
    ]
    if missing:
        raise KeyError(
            f"train_fields names {missing}, which the training records lack; they hold "
            f"{sorted(first.keys())}"
        )
    template = _held(first[None], stored, measured)[0]
    clips = len(cast(Sized, dataset))  # a map-style dataset: every store split has a length
    _check_fits(clips * template.bytes(), clips, device)
    held = template.to(device).expand(clips).clone()  # one copy, on the device
    start = 0
    loader = record_loader(dataset, 256, num_workers)
    for batch in tqdm(loader, desc="training clips to " + str(device), unit="batch", leave=False):
        held[start : start + len(batch)] = _held(batch, stored, measured).to(
            device, non_blocking=True
        )
        start += len(batch)
    if "objects" in fields:
        held["objects"] = shown_ids(held["objects"])
    if measured:
        held[MASK_FEATURES] = shown_ids(held[MASK_FEATURES], "pixels")
    return held


def _held(batch: TensorDictBase, stored: Sequence[str], measured: bool) -> TensorDictBase:
    """What is held of a batch of records: its ``stored`` fields and, if ``measured``, the
    ``per_id`` measures of its mask and frames (and its depth, where it has one: the RGB-D
    rung's) as ``MASK_FEATURES``."""
    held = batch.select(*stored)
    if measured:
        depth = batch["depth"] if "depth" in batch.keys() else None
        measures = per_id(batch["mask"], batch["frames"], depth)
        held[MASK_FEATURES] = TensorDict(measures, batch_size=[len(batch)])
    return held


def shown_ids(objects: TensorDictBase, seen: str = "visible_fraction") -> TensorDictBase:
    """``objects`` [N, T, K, ...] cut to the ids up to the highest that any clip shows (its
    ``seen`` > 0): an id no clip shows has no pixel and is never a slot, and a record's K (33)
    is several times the ids a scene uses (5), so each batch gathers and reads that much less."""
    shown = (objects[seen] > 0).flatten(0, 1).any(0).nonzero()
    count = int(shown.max()) + 1 if len(shown) else 1
    return objects.apply(lambda value: value[:, :, :count].clone())


class ResidentBatches:
    """Batches of ``batch_size`` clips (the last incomplete one dropped) in the order
    ``sampler`` gives, gathered from ``records`` [N] on their device. Under DDP each rank
    takes every world-size-th batch, so the ranks see disjoint clips."""

    def __init__(self, records: TensorDictBase, sampler: SizedSampler, batch_size: int) -> None:
        self.records, self.sampler, self.batch_size = records, sampler, batch_size

    def _rank(self) -> tuple[int, int]:
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            return torch.distributed.get_rank(), torch.distributed.get_world_size()
        return 0, 1

    def __len__(self) -> int:
        rank, world = self._rank()
        return len(range(rank, len(self.sampler) // self.batch_size, world))

    def __iter__(self) -> Iterator[TensorDictBase]:
        rank, world = self._rank()
        order = torch.as_tensor(list(self.sampler), dtype=torch.int64).to(self.records.device)
        batches = len(order) // self.batch_size
        for index in range(rank, batches, world):
            yield self.records[order[index * self.batch_size : (index + 1) * self.batch_size]]
