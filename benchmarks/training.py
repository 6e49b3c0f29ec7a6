"""Training throughput of the VRNN-LRU (docs/architecture.md §10): the float32 NCHW baseline beside
the fast path (the model's defaults: channels-last, bf16 autocast where the device supports it;
``torch.compile`` on a GPU unless ``--compile off``), as sequences per second and their ratio,
for the quickstart-size and paper-size models of ``configs/quickstart.yaml`` and ``configs/paper.yaml``.

The two paths are measured interleaved in one process (alternating rounds of timed steps, the
order swapped every round), so load from other processes hits both alike; the table gives each
path's median rate and the median of the per-round ratios. FLOPs of one training step (forward
+ backward) are counted with ``torch.utils.flop_counter.FlopCounterMode`` (matmuls and
convolutions only, so achieved FLOP/s is a lower bound). Runs on the CPU always and on CUDA when
a GPU is present.

    python benchmarks/training.py --device cpu --threads 2 --rounds 7
    python benchmarks/training.py --device cuda              # GPU: fast path bf16 + compile
    python benchmarks/training.py --device cuda --compile off  # GPU: bf16 alone
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch
import yaml
from tensordict import TensorDict
from torch.utils.flop_counter import FlopCounterMode

from voe_lightning.model import VRNNLRUModel

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


#: Left to the benchmark: the optimizer and fast-path settings it sets itself, and the memory's
#: reading, which stays VRNNLRUModel's default (the timings in docs/performance.md were taken with
#: it, before configs/paper.yaml read the memory as the paper does).
NOT_FROM_CONFIG = ("learning_rate", "adam_betas", "compile_model", "channels_last", "precision",
                   "controller_sees_read", "least_used_slots")


def config_sizes(name: str) -> tuple[dict, int]:
    """Model sizes and batch size of ``configs/<name>.yaml``, so it measures the model the
    config trains (up to ``NOT_FROM_CONFIG``)."""
    config = yaml.safe_load((CONFIGS / f"{name}.yaml").read_text())
    arguments = dict(config["model"].get("init_args") or {})
    for setting in NOT_FROM_CONFIG:
        arguments.pop(setting, None)
    return arguments, config["data"]["init_args"]["batch_size"]


SIZES = {name: config_sizes(name) for name in ("quickstart", "paper")}
#: 2M steps x batch 10 (paper §4.1).
PAPER_SEQUENCES = 2_000_000 * 10


def synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def matmul_flops_per_second(device: torch.device, dtype: torch.dtype, size: int, repeats: int) -> float:
    """Measured rate of a large square matmul (2 n^3 FLOPs each)."""
    a = torch.randn(size, size, device=device, dtype=dtype)
    b = torch.randn(size, size, device=device, dtype=dtype)
    a @ b  # warm up
    synchronize(device)
    start = time.perf_counter()
    for _ in range(repeats):
        a @ b
    synchronize(device)
    return 2 * size**3 * repeats / (time.perf_counter() - start)


def training_step(model: VRNNLRUModel, optimizer: torch.optim.Optimizer, batch: TensorDict) -> None:
    optimizer.zero_grad(set_to_none=True)
    model._step(batch)["loss"].backward()
    optimizer.step()


def make_path(name: str, device: torch.device, fast: bool, compile_model: bool, frames: int,
              batch_size: int | None = None):
    """A model, its optimizer and a random batch (the config's batch size unless given) for the
    baseline (``fast=False``: float32, NCHW) or the fast path (the model's defaults), with the
    same initial weights."""
    sizes, config_batch_size = SIZES[name]
    batch_size = batch_size or config_batch_size
    torch.manual_seed(0)
    switches = {} if fast else {"channels_last": False, "precision": "float32"}
    model = VRNNLRUModel(**sizes, learning_rate=1e-4, compile_model=fast and compile_model,
                         **switches)
    model = model.to(device)
    height, width = model.image_size
    batch = TensorDict(
        frames=torch.randint(0, 256, (batch_size, frames, height, width, 3), dtype=torch.uint8),
        batch_size=[batch_size],
    ).to(device)
    return model, model.configure_optimizers()["optimizer"], batch


def count_flops(model: VRNNLRUModel, batch: TensorDict) -> float:
    """FLOPs of one forward + backward (this also warms up allocator and oneDNN primitives)."""
    counter = FlopCounterMode(display=False)
    with counter:
        model._step(batch)["loss"].backward()
    model.zero_grad(set_to_none=True)
    return counter.get_total_flops()


def timed_steps(path, steps: int, device: torch.device) -> float:
    """Seconds per training step over ``steps`` consecutive steps."""
    synchronize(device)
    start = time.perf_counter()
    for _ in range(steps):
        training_step(*path)
    synchronize(device)
    return (time.perf_counter() - start) / steps


def benchmark(name: str, device: torch.device, steps: int, rounds: int, frames: int,
              compile_model: bool, batch_size: int | None = None) -> list[dict]:
    """Baseline and fast-path rows for one model size, measured in interleaved rounds."""
    paths = {
        "baseline": make_path(name, device, False, compile_model, frames, batch_size),
        "fast": make_path(name, device, True, compile_model, frames, batch_size),
    }
    flops = count_flops(paths["baseline"][0], paths["baseline"][2])
    for path in paths.values():
        training_step(*path)  # warm up (compile, oneDNN primitives, cuDNN autotune)
    seconds = {key: [] for key in paths}
    for round_index in range(rounds):
        order = list(paths) if round_index % 2 == 0 else list(reversed(paths))
        for key in order:
            seconds[key].append(timed_steps(paths[key], steps, device))
    ratios = [base / fast for base, fast in zip(seconds["baseline"], seconds["fast"])]
    batch_size = paths["fast"][2].batch_size[0]
    rows = []
    for key, (model, _, _) in paths.items():
        step = statistics.median(seconds[key])
        rows.append({
            "model": name,
            "device": device.type,
            "path": key,
            "layout": "NHWC" if model.hparams.channels_last else "NCHW",
            "precision": "bf16-autocast" if model.uses_bf16 else "float32",
            "compiled": bool(model.hparams.compile_model),
            "batch": batch_size,
            "parameters": sum(p.numel() for p in model.parameters()),
            "gflop_per_step": flops / 1e9,
            "step_ms": step * 1e3,
            "sequences_per_s": batch_size / step,
            "ratio": statistics.median(ratios) if key == "fast" else 1.0,
            "ratio_range": (min(ratios), max(ratios)),
            "achieved_gflops": flops / step / 1e9,
            "paper_run_hours": PAPER_SEQUENCES / (batch_size / step) / 3600,
        })
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", choices=("all", "cpu", "cuda"), default="all")
    parser.add_argument("--models", nargs="+", choices=tuple(SIZES), default=list(SIZES))
    parser.add_argument("--steps", type=int, default=None,
                        help="timed steps per path and round (default: 3 quickstart / 1 paper on "
                        "CPU, 20 on GPU)")
    parser.add_argument("--rounds", type=int, default=5,
                        help="interleaved rounds (baseline, fast, fast, baseline, ...) per model")
    parser.add_argument("--threads", type=int, default=None,
                        help="CPU threads (torch.set_num_threads); on a shared, busy machine 1 is "
                        "much faster than several spin-waiting OpenMP threads")
    parser.add_argument("--batch-size", type=int, default=None,
                        help="sequences per step (default: the config's, 8 quickstart / 10 paper); "
                        "a GPU is better measured at a batch that fills it, e.g. 64")
    parser.add_argument("--frames", type=int, default=15, help="frames per sequence (paper: 15)")
    parser.add_argument("--compile", choices=("auto", "on", "off"), default="auto",
                        help="torch.compile the fast path: auto = on a GPU only (compiling takes "
                        "minutes on a CPU); off gives the GPU column of bf16 alone")
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)

    devices = []
    if args.device in ("all", "cpu"):
        devices.append(torch.device("cpu"))
    if args.device in ("all", "cuda"):
        if torch.cuda.is_available():
            devices.append(torch.device("cuda"))
        elif args.device == "cuda":
            parser.error("--device cuda asked for, but torch.cuda.is_available() is False")

    rows = []
    for device in devices:
        if device.type == "cuda":
            torch.backends.cuda.matmul.allow_tf32 = True
            torch.backends.cudnn.allow_tf32 = True
            peaks = {
                "float32 (tf32)": matmul_flops_per_second(device, torch.float32, 8192, 20),
                "bfloat16": matmul_flops_per_second(device, torch.bfloat16, 8192, 50),
            }
            name = torch.cuda.get_device_name(device)
        else:
            peaks = {"float32": matmul_flops_per_second(device, torch.float32, 2048, 10)}
            name = f"CPU, {torch.get_num_threads()} threads"
        print(f"\n{name}: measured matmul " + ", ".join(f"{k} {v / 1e9:,.0f} GFLOP/s" for k, v in peaks.items()))
        peak = peaks["bfloat16"] if device.type == "cuda" else peaks["float32"]
        for model_name in args.models:
            steps = args.steps or (20 if device.type == "cuda" else (3 if model_name == "quickstart" else 1))
            compile_model = args.compile == "on" or (args.compile == "auto" and device.type == "cuda")
            for row in benchmark(model_name, device, steps, args.rounds, args.frames, compile_model,
                                 args.batch_size):
                row["of_matmul_peak"] = row["achieved_gflops"] * 1e9 / peak
                rows.append(row)

    header = (f"{'model':<11}{'device':<7}{'path':<9}{'layout':<7}{'precision':<15}{'compiled':<9}"
              f"{'batch':>6}{'params':>11}{'GFLOP/step':>12}{'ms/step':>10}{'seq/s':>9}"
              f"{'ratio':>7}{'(range)':>13}{'GFLOP/s':>10}{'of peak':>9}{'20M seq (h)':>13}")
    print("\n" + header + "\n" + "-" * len(header))
    for r in rows:
        spread = f"{r['ratio_range'][0]:.2f}-{r['ratio_range'][1]:.2f}" if r["path"] == "fast" else ""
        print(f"{r['model']:<11}{r['device']:<7}{r['path']:<9}{r['layout']:<7}{r['precision']:<15}"
              f"{'yes' if r['compiled'] else 'no':<9}{r['batch']:>6}{r['parameters']:>11,}"
              f"{r['gflop_per_step']:>12.2f}{r['step_ms']:>10.1f}{r['sequences_per_s']:>9.1f}"
              f"{r['ratio']:>6.2f}x{spread:>13}{r['achieved_gflops']:>10.1f}"
              f"{r['of_matmul_peak']:>9.1%}{r['paper_run_hours']:>13.1f}")
    print(f"\nT={args.frames} frames of 64x64; {args.rounds} interleaved rounds per model; seq/s is "
          "each path's median, ratio the median of the per-round fast/baseline ratios (range: "
          "min-max); FLOPs of forward+backward counted by FlopCounterMode; '20M seq (h)' = hours "
          "for the paper's 2M steps x batch 10 at this rate.")


if __name__ == "__main__":
    main()
