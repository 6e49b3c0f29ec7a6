"""Where a VRNN-LRU training step's time goes on the CPU, per path (eager, compiled): the self
time of its ops in a ``torch.profiler`` trace, grouped as convolutions (forward and backward), the compiled
graphs' own kernels, matrix products and the rest (pointwise work, copies, reductions, the
optimizer). It says how much compiling can save at most: only what is not a convolution.

    python benchmarks/step_profile.py --threads 2 --config paper

On a GPU a trace's CPU self time is launch time, not the kernels': use ``training.py`` there.
"""

from __future__ import annotations

import argparse
import collections
import time

import torch
from torch.profiler import ProfilerActivity, profile
from training import PATHS, config_sizes

from voe_lightning.model import VRNNLRUModel

GROUPS = {
    "convolutions": ("aten::convolution_backward", "aten::mkldnn_convolution"),
    "compiled kernels": ("## Call CompiledFxGraph",),
    "matrix products": ("aten::mm", "aten::addmm", "aten::bmm", "aten::linear"),
}


def group_of(name: str) -> str:
    """The group of a profiled op's name (``rest`` when none matches)."""
    return next((g for g, prefixes in GROUPS.items() if name.startswith(prefixes)), "rest")


def training_step(model: VRNNLRUModel, optimizer: torch.optim.Optimizer, frames: torch.Tensor):
    """Forward, backward and an Adam step on one batch of uint8 clips."""
    noise = model.core.draw_noise(frames.shape[0], frames.shape[1], frames.device)
    model.training_terms(frames, noise, torch.ones(()))[0].backward()
    optimizer.step()
    optimizer.zero_grad(set_to_none=True)


def profile_path(config: str, path: str, steps: int) -> dict[str, float]:
    """Milliseconds a step per group (and ``step``: the unprofiled wall time) for one path."""
    arguments, batch_size = config_sizes(config)
    model = VRNNLRUModel(**arguments, **PATHS[path]).train()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-5)
    height, width = model.image_size
    frames = torch.randint(0, 256, (batch_size, 15, height, width, 3), dtype=torch.uint8)
    for _ in range(3):  # compiles, warms the allocator and oneDNN's caches
        training_step(model, optimizer, frames)
    start = time.perf_counter()
    for _ in range(steps):
        training_step(model, optimizer, frames)
    times = {"step": (time.perf_counter() - start) / steps * 1e3}
    with profile(activities=[ProfilerActivity.CPU]) as trace:
        for _ in range(steps):
            training_step(model, optimizer, frames)
    grouped = collections.Counter()
    for event in trace.key_averages():
        grouped[group_of(event.key)] += event.self_cpu_time_total / 1e3 / steps
    return times | dict(grouped)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--config", default="paper", help="configs/<name>.yaml's model and batch")
    parser.add_argument(
        "--paths", nargs="+", default=["eager", "compiled"], choices=["eager", "compiled"]
    )
    parser.add_argument("--steps", type=int, default=3)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    rows = {path: profile_path(args.config, path, args.steps) for path in args.paths}
    groups = [*GROUPS, "rest"]
    print(f"{args.config}, cpu, {torch.get_num_threads()} threads: self time a step (ms)")
    print("| path | step (ms, unprofiled) | " + " | ".join(groups) + " | not a convolution |")
    print("|---" * (len(groups) + 3) + "|")
    for path, row in rows.items():
        total = sum(row.get(g, 0.0) for g in groups)
        cells = [f"{row.get(g, 0.0):,.0f} ({row.get(g, 0.0) / total:.0%})" for g in groups]
        other = 1 - row.get("convolutions", 0.0) / total
        print(f"| {path} | {row['step']:,.0f} | " + " | ".join(cells) + f" | {other:.0%} |")


if __name__ == "__main__":
    main()
