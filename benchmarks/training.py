"""Training throughput of the VRNN-LRU (DESIGN.md §7): sequences per second and achieved FLOP/s
for the quickstart-size and paper-size models, beside the machine's measured matmul rate.

FLOPs of one training step (forward + backward) are counted with
``torch.utils.flop_counter.FlopCounterMode`` (matmuls and convolutions; elementwise work is not
counted, so achieved FLOP/s is a lower bound on the arithmetic done). Runs on the CPU always and
on CUDA (bf16 autocast) when a GPU is present.

    python benchmarks/training.py                 # CPU (and GPU if any), both sizes
    python benchmarks/training.py --device cuda --steps 50 --compile
"""

from __future__ import annotations

import argparse
import contextlib
import time
from pathlib import Path

import torch
import yaml
from tensordict import TensorDict
from torch.utils.flop_counter import FlopCounterMode

from voe_lightning.model import VOEModel

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def config_sizes(name: str) -> tuple[dict, int]:
    """Model arguments (optimizer settings left out) and batch size of ``configs/<name>.yaml``,
    so the benchmark measures exactly the model the config trains."""
    config = yaml.safe_load((CONFIGS / f"{name}.yaml").read_text())
    arguments = dict(config["model"].get("init_args") or {})
    for optimizer_setting in ("learning_rate", "adam_betas"):
        arguments.pop(optimizer_setting, None)
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


def autocast(device: torch.device) -> contextlib.AbstractContextManager:
    if device.type == "cuda":
        return torch.autocast("cuda", dtype=torch.bfloat16)
    return contextlib.nullcontext()


def training_step(model: VOEModel, optimizer: torch.optim.Optimizer, batch: TensorDict, device) -> None:
    optimizer.zero_grad(set_to_none=True)
    with autocast(device):
        loss = model._step(batch)["loss"]
    loss.backward()
    optimizer.step()


def benchmark(name: str, device: torch.device, steps: int, frames: int, compile_model: bool) -> dict:
    sizes, batch_size = SIZES[name]
    torch.manual_seed(0)
    model = VOEModel(**sizes, learning_rate=1e-4, compile_model=compile_model).to(device)
    optimizer = model.configure_optimizers()
    height, width = model.image_size
    batch = TensorDict(
        frames=torch.randint(0, 256, (batch_size, frames, height, width, 3), dtype=torch.uint8),
        batch_size=[batch_size],
    ).to(device)

    # The counted step also warms up the CPU path (allocator, oneDNN primitives).
    counter = FlopCounterMode(display=False)
    optimizer.zero_grad(set_to_none=True)
    with counter:
        with autocast(device):
            loss = model._step(batch)["loss"]
        loss.backward()
    flops = counter.get_total_flops()

    if compile_model or device.type == "cuda":
        training_step(model, optimizer, batch, device)  # warm up (compile, cuDNN autotune)
    synchronize(device)
    start = time.perf_counter()
    for _ in range(steps):
        training_step(model, optimizer, batch, device)
    synchronize(device)
    seconds = (time.perf_counter() - start) / steps
    return {
        "model": name,
        "device": device.type,
        "precision": "bf16-autocast" if device.type == "cuda" else "float32",
        "batch": batch_size,
        "parameters": sum(p.numel() for p in model.parameters()),
        "gflop_per_step": flops / 1e9,
        "step_ms": seconds * 1e3,
        "sequences_per_s": batch_size / seconds,
        "achieved_gflops": flops / seconds / 1e9,
        "paper_run_hours": PAPER_SEQUENCES / (batch_size / seconds) / 3600,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", choices=("all", "cpu", "cuda"), default="all")
    parser.add_argument("--models", nargs="+", choices=tuple(SIZES), default=list(SIZES))
    parser.add_argument("--steps", type=int, default=None,
                        help="timed steps per model (default: 5 quickstart / 1 paper on CPU, 50 on GPU)")
    parser.add_argument("--threads", type=int, default=None,
                        help="CPU threads (torch.set_num_threads); on a shared, busy machine 1 is "
                        "much faster than several spin-waiting OpenMP threads")
    parser.add_argument("--frames", type=int, default=15, help="frames per sequence (paper: 15)")
    parser.add_argument("--compile", action="store_true", help="torch.compile the networks")
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
            steps = args.steps or (50 if device.type == "cuda" else (5 if model_name == "quickstart" else 1))
            row = benchmark(model_name, device, steps, args.frames, args.compile)
            row["of_matmul_peak"] = row["achieved_gflops"] * 1e9 / peak
            rows.append(row)

    header = (f"{'model':<11}{'device':<7}{'precision':<15}{'batch':>6}{'params':>11}"
              f"{'GFLOP/step':>12}{'ms/step':>10}{'seq/s':>9}{'GFLOP/s':>10}{'of peak':>9}"
              f"{'20M seq (h)':>13}")
    print("\n" + header + "\n" + "-" * len(header))
    for r in rows:
        print(f"{r['model']:<11}{r['device']:<7}{r['precision']:<15}{r['batch']:>6}"
              f"{r['parameters']:>11,}{r['gflop_per_step']:>12.2f}{r['step_ms']:>10.1f}"
              f"{r['sequences_per_s']:>9.1f}{r['achieved_gflops']:>10.1f}"
              f"{r['of_matmul_peak']:>9.1%}{r['paper_run_hours']:>13.1f}")
    print(f"\nT={args.frames} frames of 64x64; FLOPs of forward+backward counted by FlopCounterMode; "
          "'20M seq (h)' = hours for the paper's 2M steps x batch 10 at this rate.")


if __name__ == "__main__":
    main()
