"""Training throughput of the positive control (``configs/object_state.yaml``): training steps
per second at the config's batch size and model size, on real batches of the config's training
clips, per thread count, and what ``fit``'s max_steps then take (the issue's budget: fit + test
within 15 minutes on a 2-core CPU). Data loading is outside the timing; the model is small, so
the time goes into many small tensor operations, and a second thread helps little.

    python benchmarks/positive_control.py --threads 1 2 --steps 30
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch
import yaml
from torch.utils.data import ConcatDataset, DataLoader

from voe_lightning import specs
from voe_lightning.data.store import collate, open_split
from voe_lightning.model import ObjectStateModel

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "object_state.yaml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--steps", type=int, default=30, help="timed steps per thread count")
    parser.add_argument("--warmup", type=int, default=3)
    args = parser.parse_args()
    config = yaml.safe_load(CONFIG.read_text())
    data, model_args = config["data"]["init_args"], config["model"]["init_args"]
    root = CONFIG.parents[1] / data["root"]
    if not (root / "manifest.json").exists():
        raise SystemExit(
            f"no training clips at {root}; run `python -m voe_lightning fit "
            f"--config {CONFIG.relative_to(CONFIG.parents[1])}` (it generates "
            "them first) or `python -m voe_lightning generate` for that root"
        )
    train = ConcatDataset([open_split(root, concept, "train") for concept in specs.CONCEPTS])
    loader = DataLoader(
        train,
        batch_size=data["batch_size"],
        shuffle=True,
        collate_fn=collate,
        drop_last=True,
        generator=torch.Generator().manual_seed(0),
    )
    batches = [batch for batch, _ in zip(loader, range(args.warmup + args.steps))]
    max_steps = config["trainer"]["max_steps"]
    print(
        f"positive control, batch {data['batch_size']}, hidden {model_args['hidden_size']}, "
        f"{args.steps} timed steps"
    )
    print("| threads | step (s), median | steps/s | fit of max_steps |")
    print("|---|---|---|---|")
    for threads in args.threads:
        torch.set_num_threads(threads)
        torch.manual_seed(0)
        model = ObjectStateModel(**{k: v for k, v in model_args.items() if k != "lr_schedule"})
        model.log = lambda *_, **__: None
        optimizer = torch.optim.Adam(model.parameters(), lr=model_args["learning_rate"])
        times = []
        for index, batch in enumerate(batches):
            start = time.perf_counter()
            loss = model.training_step(batch, index)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            if index >= args.warmup:
                times.append(time.perf_counter() - start)
        step = statistics.median(times)
        minutes, seconds = divmod(round(step * max_steps), 60)
        print(
            f"| {threads} | {step:.3f} | {1 / step:.2f} | {max_steps} steps: "
            f"{minutes} min {seconds:02d} s |"
        )


if __name__ == "__main__":
    main()
