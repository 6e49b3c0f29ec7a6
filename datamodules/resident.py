"""Training batches gathered from clips held whole on the training device as uint8, so that at
thousands of sequences a second loading never waits on the host: one gather kernel a batch, no
worker processes, no host-to-device copy. Frames only: for models trained from pixels (the
VRNN-LRU); the paper-scale set (about 184 GB at 15 frames of 64x64) does not fit one GPU."""

from __future__ import annotations

from collections.abc import Iterator

import torch
from tensordict import TensorDict
from torch.utils.data import Dataset, Sampler
from tqdm import tqdm

from voe_lightning.data.store import record_loader


def resident_frames(dataset: Dataset, device: torch.device, num_workers: int = 0) -> torch.Tensor:
    """Every record's ``frames`` as one uint8 tensor [N, T, H, W, 3] on ``device``, in dataset
    order; refused, naming the sizes, when it would not fit the device's free memory."""
    first = dataset[0]["frames"]
    needed = len(dataset) * first.numel()
    if device.type == "cuda":
        free, _ = torch.cuda.mem_get_info(device)
        if needed > 0.8 * free:
            raise MemoryError(
                f"the {len(dataset):,} training clips need {needed / 2**30:.1f} GiB on {device}, "
                f"which has {free / 2**30:.1f} GiB free; set train_on_device: false (worker "
                "processes load them) or train on fewer clips"
            )
    frames = torch.empty((len(dataset), *first.shape), dtype=torch.uint8, device=device)
    start = 0
    loader = record_loader(dataset, 256, num_workers)
    for batch in tqdm(loader, desc="training clips to " + str(device), unit="batch", leave=False):
        frames[start : start + len(batch)] = batch["frames"].to(device, non_blocking=True)
        start += len(batch)
    return frames


class ResidentBatches:
    """Batches of ``batch_size`` clips (the last incomplete one dropped) in the order
    ``sampler`` gives, gathered from ``frames`` [N, ...] on their device. Under DDP each rank
    takes every world-size-th batch, so the ranks see disjoint clips."""

    def __init__(self, frames: torch.Tensor, sampler: Sampler[int], batch_size: int) -> None:
        self.frames, self.sampler, self.batch_size = frames, sampler, batch_size

    def _rank(self) -> tuple[int, int]:
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            return torch.distributed.get_rank(), torch.distributed.get_world_size()
        return 0, 1

    def __len__(self) -> int:
        rank, world = self._rank()
        return len(range(rank, len(self.sampler) // self.batch_size, world))

    def __iter__(self) -> Iterator[TensorDict]:
        rank, world = self._rank()
        order = torch.as_tensor(list(self.sampler), dtype=torch.int64).to(self.frames.device)
        batches = len(order) // self.batch_size
        for index in range(rank, batches, world):
            rows = order[index * self.batch_size : (index + 1) * self.batch_size]
            yield TensorDict(frames=self.frames[rows], batch_size=[self.batch_size])
