"""Training throughput of the object-state learner (``--config``: the positive control,
``configs/object_state.yaml``; the learned result, ``configs/learned_states.yaml``; its mask
rung, ``configs/learned_masks.yaml``): training steps and clips per second on real batches of
the config's training clips, per thread count, batch size and hidden size (default: the
config's), and what ``fit``'s max_steps then take. Data loading is outside the timing; the model
is small, so the time goes into many small tensor operations, and a second thread helps little.

    python benchmarks/positive_control.py --threads 1 2 --steps 30
    python benchmarks/positive_control.py --config configs/learned_states.yaml \
        --batch-size 32 512 --hidden-size 128 32 --threads 2 --steps 5
"""

from __future__ import annotations

import argparse
import itertools
import platform
import statistics
import time
from pathlib import Path

import torch
import yaml
from torch.utils.data import ConcatDataset, DataLoader

from voe_lightning import specs
from voe_lightning.data.store import collate, open_split
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
    loader = DataLoader(
        train,
        batch_size=max(batch_sizes),
        shuffle=True,
        collate_fn=collate,
        drop_last=True,
        generator=torch.Generator().manual_seed(0),
    )
    batches = [batch for batch, _ in zip(loader, range(args.warmup + args.steps))]
    max_steps = config["trainer"]["max_steps"]
    print(f"{args.config}: {args.steps} timed steps on {cpu_name()}")
    print("| threads | batch | hidden | step (s), median | steps/s | clips/s | fit of max_steps |")
    print("|---|---|---|---|---|---|---|")
    for threads, batch_size, hidden in itertools.product(
        args.threads, batch_sizes, args.hidden_size or [model_args["hidden_size"]]
    ):
        torch.set_num_threads(threads)
        torch.manual_seed(0)
        arguments = {k: v for k, v in model_args.items() if k != "lr_schedule"}
        arguments |= {"hidden_size": hidden, "message_size": max(1, hidden // 2)}
        model = ObjectStateModel(**arguments)
        model.log = lambda *_, **__: None
        optimizer = torch.optim.Adam(model.parameters(), lr=model_args["learning_rate"])
        times = []
        for index, batch in enumerate(batches):
            start = time.perf_counter()
            loss = model.training_step(batch[:batch_size], index)
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
