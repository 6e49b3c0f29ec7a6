"""Training throughput of the object-state learner (``--config``: the positive control,
``configs/object_state.yaml``; the learned result, ``configs/learned_states.yaml``): training
steps and clips per second on real batches of the config's training clips, per thread count,
batch size and hidden size (default: the config's), and what ``fit``'s max_steps then take.
Batches come as ``fit`` serves them with the config's ``train_fields`` (``[objects, camera]``:
the states; the mask rung's ``[mask_features, camera]``: each clip's mask measures) held in
memory, one gather a batch, inside the timing (decoding and measuring them once is not);
``--clips N`` holds the first N clips only, for a quicker start. ``--model`` sets
model arguments over the config's (e.g. ``'{"sight_lines": false}'``). ``--objects N`` times
batches of only the clips that show N objects (each step rolls a batch's clips out grouped by
how many objects they show, ``by_object_count``, so no slot pair is run for an empty slot).
``--processes P`` trains data-parallel as ``fit --trainer.strategy ddp --trainer.devices P
--trainer.accelerator cpu`` does: P processes of ``--threads`` threads each, each stepping on
its share of every batch (batch / P clips), gradients averaged by PyTorch's
DistributedDataParallel.

    python benchmarks/positive_control.py --threads 1 2 --steps 30
    python benchmarks/positive_control.py --config configs/learned_states.yaml \
        --batch-size 32 512 --hidden-size 128 64 --threads 2 --steps 5
    python benchmarks/positive_control.py --config configs/learned_states.yaml \
        --batch-size 4096 --hidden-size 64 --threads 1 --processes 2 --steps 3 --warmup 1
    python benchmarks/positive_control.py --config configs/masks_15min.yaml --clips 4096 \
        --batch-size 32 2048 --hidden-size 128 64 --threads 2 --steps 5 --warmup 1
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import platform
import socket
import statistics
import time
from pathlib import Path

import torch
import torch.distributed as dist
import torch.multiprocessing as mp
import yaml
from torch import nn
from torch.utils.data import ConcatDataset, Subset

from voe_lightning import specs
from voe_lightning.data.store import open_split
from voe_lightning.datamodules.resident import ResidentBatches, resident_records
from voe_lightning.datamodules.voe import InterleavedSampler
from voe_lightning.model import ObjectStateModel

REPO = Path(__file__).resolve().parents[1]


def cpu_name() -> str:
    """The CPU's model name (Linux's /proc/cpuinfo), else the machine type."""
    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.exists() else []
    names = [line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")]
    return names[0] if names else platform.machine()


class TrainingStep(nn.Module):
    """The model's training step as a module's forward, so DistributedDataParallel (which
    averages gradients through forward's hooks) can wrap it."""

    def __init__(self, model: ObjectStateModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, batch, index: int) -> torch.Tensor:
        return self.model.training_step(batch, index)


def held_clips(args: argparse.Namespace, root: Path, fields: list[str]):
    """The training clips' ``fields`` held in memory and the order ``fit`` serves them in."""
    parts = [open_split(root, concept, "train") for concept in specs.CONCEPTS]
    if args.clips is not None:  # the first clips of each concept, in equal shares
        share = -(-args.clips // len(parts))
        parts = [Subset(part, range(min(share, len(part)))) for part in parts]
    train = ConcatDataset(parts)
    held = resident_records(train, fields, torch.device("cpu"))
    sampler = InterleavedSampler([len(part) for part in train.datasets])
    if args.objects is not None:
        if "objects" not in fields:
            raise SystemExit(f"--objects counts the states' objects; {args.config} holds {fields}")
        shown = (held["objects", "visible_fraction"] > 0).any(1)[:, 1:].sum(1)  # id 0: background
        chosen = (shown == args.objects).nonzero()[:, 0]
        if len(chosen) == 0:
            raise SystemExit(f"no training clip shows {args.objects} objects")
        held, sampler = held[chosen], torch.randperm(len(chosen)).repeat(64).tolist()
    return held, sampler


def median_step(
    args: argparse.Namespace, held, sampler, model_args: dict, batch_size: int, hidden: int
) -> float:
    """The median seconds of a training step (gather, forward, backward, Adam) of a model of
    width ``hidden`` on batches of ``batch_size`` clips (this process's share under DDP)."""
    torch.manual_seed(0)
    arguments = {k: v for k, v in model_args.items() if k != "lr_schedule"} | args.model
    arguments |= {"hidden_size": hidden, "message_size": max(1, hidden // 2)}
    model = ObjectStateModel(**arguments)
    model.log = lambda *_, **__: None
    step = TrainingStep(model)
    if dist.is_initialized():
        step = nn.parallel.DistributedDataParallel(step)
    optimizer = torch.optim.Adam(model.parameters(), lr=model_args["learning_rate"])
    epochs = itertools.repeat(ResidentBatches(held, sampler, batch_size))
    batches = itertools.chain.from_iterable(epochs)  # large batches run past one epoch
    times = []
    for index in range(args.warmup + args.steps):
        start = time.perf_counter()
        loss = step(next(batches), index)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if index >= args.warmup:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def process_step(
    rank: int, world: int, port: int, args, root, fields, model_args, sizes, results
) -> None:
    """One data-parallel process: its share of each batch, timed; rank 0 reports the medians."""
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    dist.init_process_group("gloo", rank=rank, world_size=world)
    torch.set_num_threads(args.threads[0])
    held, sampler = held_clips(args, root, fields)
    for batch_size, hidden in sizes:
        step = median_step(args, held, sampler, model_args, batch_size // world, hidden)
        if rank == 0:
            results.put((batch_size, hidden, step))
    dist.destroy_process_group()


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--steps", type=int, default=30, help="timed steps per thread count")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--config", default="configs/object_state.yaml")
    parser.add_argument("--batch-size", type=int, nargs="+", help="default: the config's")
    parser.add_argument("--hidden-size", type=int, nargs="+", help="default: the config's")
    parser.add_argument("--model", type=json.loads, default={}, help="model arguments (JSON)")
    parser.add_argument("--objects", type=int, help="only clips showing this many objects")
    parser.add_argument(
        "--processes", type=int, default=1, help="data-parallel processes (DDP), each --threads"
    )
    parser.add_argument("--clips", type=int, help="hold only the first N training clips")
    args = parser.parse_args()
    config = yaml.safe_load((REPO / args.config).read_text())
    data, model_args = config["data"]["init_args"], config["model"]["init_args"]
    root = REPO / data["root"]
    fields = data.get("train_fields") or ["objects", "camera"]
    if not (root / "manifest.json").exists():
        raise SystemExit(
            f"no training clips at {root}; run `python -m voe_lightning fit "
            f"--config {args.config}` (it generates them first) or `python -m voe_lightning "
            "generate` for that root"
        )
    if args.processes > 1 and len(args.threads) > 1:
        raise SystemExit(f"--processes {args.processes} takes one --threads, got {args.threads}")
    sizes = list(
        itertools.product(
            args.batch_size or [data["batch_size"]], args.hidden_size or [model_args["hidden_size"]]
        )
    )
    max_steps = config["trainer"]["max_steps"]
    only = "" if args.objects is None else f", clips showing {args.objects} objects"
    print(f"{args.config} {args.model or ''}{only}: {args.steps} timed steps on {cpu_name()}")
    print(
        "| processes | threads | batch | hidden | step (s), median | steps/s | clips/s "
        "| fit of max_steps |"
    )
    print("|---|---|---|---|---|---|---|---|")

    def row(threads: int, batch_size: int, hidden: int, step: float) -> None:
        minutes, seconds = divmod(round(step * max_steps), 60)
        print(
            f"| {args.processes} | {threads} | {batch_size} | {hidden} | {step:.3f} | "
            f"{1 / step:.2f} | {batch_size / step:.0f} | {max_steps} steps: {minutes} min "
            f"{seconds:02d} s |"
        )

    if args.processes > 1:
        results = mp.get_context("spawn").SimpleQueue()
        mp.spawn(
            process_step,
            args=(args.processes, free_port(), args, root, fields, model_args, sizes, results),
            nprocs=args.processes,
        )
        for _ in sizes:
            row(args.threads[0], *results.get())
        return
    held, sampler = held_clips(args, root, fields)
    for threads, (batch_size, hidden) in itertools.product(args.threads, sizes):
        torch.set_num_threads(threads)
        row(
            threads,
            batch_size,
            hidden,
            median_step(args, held, sampler, model_args, batch_size, hidden),
        )


if __name__ == "__main__":
    main()
