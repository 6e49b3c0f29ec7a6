"""Training throughput of the object-state learner (``--config``: the positive control,
``configs/object_state.yaml``; the learned result, ``configs/learned_states.yaml``): training
steps and clips per second on real batches of the config's training clips, per thread count,
batch size and hidden size (default: the config's), and what ``fit``'s max_steps then take.
Batches come as ``fit`` serves them with ``train_fields: [objects, camera]``: the states held in
memory, one gather a batch, inside the timing (decoding them once is not). ``--model`` sets
model arguments over the config's (e.g. ``'{"sight_lines": false}'``). ``--objects N`` times
batches of only the clips that show N objects (each step rolls a batch's clips out grouped by
how many objects they show, ``by_object_count``, so no slot pair is run for an empty slot).

    python benchmarks/positive_control.py --threads 1 2 --steps 30
    python benchmarks/positive_control.py --config configs/learned_states.yaml \
        --batch-size 32 512 --hidden-size 128 64 --threads 2 --steps 5
"""

from __future__ import annotations

import argparse
import itertools
import json
import platform
import statistics
import time
from pathlib import Path

import torch
import yaml
from torch.utils.data import ConcatDataset

from datamodules.resident import ResidentBatches, resident_records
from datamodules.voe import InterleavedSampler
from voe_lightning import specs
from voe_lightning.data.store import open_split
from voe_lightning.model import ObjectStateModel

REPO = Path(__file__).resolve().parents[1]


def cpu_name() -> str:
    """The CPU's model name (Linux's /proc/cpuinfo), else the machine type."""
    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.exists() else []
    names = [line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")]
    return names[0] if names else platform.machine()


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
    args = parser.parse_args()
    config = yaml.safe_load((REPO / args.config).read_text())
    data, model_args = config["data"]["init_args"], config["model"]["init_args"]
    root = REPO / data["root"]
    if not (root / "manifest.json").exists():
        raise SystemExit(
            f"no training clips at {root}; run `python -m voe_lightning fit "
            f"--config {args.config}` (it generates them first) or `python -m voe_lightning "
            "generate` for that root"
        )
    train = ConcatDataset([open_split(root, concept, "train") for concept in specs.CONCEPTS])
    batch_sizes = args.batch_size or [data["batch_size"]]
    held = resident_records(train, ["objects", "camera"], torch.device("cpu"))
    sampler = InterleavedSampler([len(part) for part in train.datasets])
    if args.objects is not None:
        shown = (held["objects", "visible_fraction"] > 0).any(1)[:, 1:].sum(1)  # id 0: background
        chosen = (shown == args.objects).nonzero()[:, 0]
        if len(chosen) == 0:
            raise SystemExit(f"no training clip shows {args.objects} objects")
        held, sampler = held[chosen], torch.randperm(len(chosen)).repeat(64).tolist()
    max_steps = config["trainer"]["max_steps"]
    only = "" if args.objects is None else f", clips showing {args.objects} objects"
    print(f"{args.config} {args.model or ''}{only}: {args.steps} timed steps on {cpu_name()}")
    print("| threads | batch | hidden | step (s), median | steps/s | clips/s | fit of max_steps |")
    print("|---|---|---|---|---|---|---|")
    for threads, batch_size, hidden in itertools.product(
        args.threads, batch_sizes, args.hidden_size or [model_args["hidden_size"]]
    ):
        torch.set_num_threads(threads)
        torch.manual_seed(0)
        arguments = {k: v for k, v in model_args.items() if k != "lr_schedule"} | args.model
        arguments |= {"hidden_size": hidden, "message_size": max(1, hidden // 2)}
        model = ObjectStateModel(**arguments)
        model.log = lambda *_, **__: None
        optimizer = torch.optim.Adam(model.parameters(), lr=model_args["learning_rate"])
        times = []
        epochs = itertools.repeat(ResidentBatches(held, sampler, batch_size))
        batches = itertools.chain.from_iterable(epochs)  # large batches run past one epoch
        for index in range(args.warmup + args.steps):
            start = time.perf_counter()
            loss = model.training_step(next(batches), index)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            if index >= args.warmup:
                times.append(time.perf_counter() - start)
        step = statistics.median(times)
        minutes, seconds = divmod(round(step * max_steps), 60)
        print(
            f"| {threads} | {batch_size} | {hidden} | {step:.3f} | {1 / step:.2f} | "
            f"{batch_size / step:.0f} | {max_steps} steps: {minutes} min {seconds:02d} s |"
        )


if __name__ == "__main__":
    main()
