"""Training throughput of the VRNN-LRU through ``Trainer.fit``, per path: the float32 NCHW
``reference``; ``eager`` (the model's fast defaults: channels-last, bf16 autocast where the
device has it, fused Adam, no host sync a step) with ``compile: off``; ``compiled``
(``compile: frame``: the recurrent core's one-frame step and the encoder and decoder compiled);
and on a GPU ``graphed`` (compiled, the loss's forward and backward replayed from CUDA graphs).
Sizes from ``configs/vrnn_quickstart.yaml`` and ``configs/paper.yaml``, at the config's batch and
any ``--batch-size`` more.

Clips are random uint8 held on the device (``voe_lightning.datamodules.resident``), so loading costs nothing.
Paths are timed in interleaved rounds (the order reversed every round; each round a short
``fit`` whose first steps are not timed); the table gives each path's median. Per path also:
host syncs a plain step and a read-back step (every ``log_every_n_steps`` the model reads its
loss terms back once), ATen kernels a step (those of an eager step; compiled code runs most of
its kernels outside ATen), kernel launches a step on a GPU (from a ``torch.profiler`` trace of
each step, :class:`StepCounts`), and the first fit's seconds (compiling, capturing included).

    python benchmarks/training.py --device cpu --threads 2 --json out.json
    python benchmarks/training.py --device cuda --batch-size 256 --json gpu.json
"""

from __future__ import annotations

import argparse
import collections
import json
import statistics
import time
from pathlib import Path

import torch
import yaml
from lightning.pytorch import Callback, Trainer
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils.data import SequentialSampler
from torch.utils.flop_counter import FlopCounterMode

from voe_lightning.datamodules.resident import ResidentBatches
from voe_lightning.model import VRNNLRUModel

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
#: Set by the benchmark per path, not read from the configs.
NOT_FROM_CONFIG = (
    "learning_rate",
    "adam_betas",
    "compile",
    "cuda_graph",
    "channels_last",
    "precision",
    "lr_warmup_steps",
)
PATHS = {
    "reference": dict(channels_last=False, precision="float32", compile="off", cuda_graph=False),
    "eager": dict(compile="off", cuda_graph=False),
    "compiled": dict(compile="frame", cuda_graph=False),
    "graphed": dict(compile="frame", cuda_graph=True),
}
#: ATen ops that read a device tensor back to the host. Only calls from Python count: inside an
#: ATen kernel they are the CPU kernel's own reads (the CPU's fused Adam reads each step count).
SYNC_OPS = {
    "aten::_local_scalar_dense",
    "aten::item",
    "aten::is_nonzero",
    "aten::nonzero",
    "aten::masked_select",
}
#: 2M steps x batch 10 (paper §4.1).
PAPER_SEQUENCES = 2_000_000 * 10
#: Read-back cadence of the counting fit (a few steps, each profiled) and of the timed fits
#: (the configs log every 25 to 100 steps).
LOG_EVERY, TIMED_LOG_EVERY = 4, 50


#: The config each size is read from: the quickstart size is the VRNN-LRU's quickstart.
CONFIG_OF = {"quickstart": "vrnn_quickstart", "paper": "paper"}


def config_sizes(name: str) -> tuple[dict, int]:
    """Model sizes and batch size of size ``name``'s config (``CONFIG_OF``; less
    ``NOT_FROM_CONFIG``)."""
    config = yaml.safe_load((CONFIGS / f"{CONFIG_OF[name]}.yaml").read_text())
    arguments = dict(config["model"].get("init_args") or {})
    for setting in NOT_FROM_CONFIG:
        arguments.pop(setting, None)
    return arguments, config["data"]["init_args"]["batch_size"]


def synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _inside_aten(event) -> bool:
    """Whether a profiler event was called by an ATen op (not from Python)."""
    parent = event.cpu_parent
    while parent is not None:
        if parent.name.startswith("aten::"):
            return True
        parent = parent.cpu_parent
    return False


class OpCounter(TorchDispatchMode):
    """Counts the ATen ops an eager step dispatches (torch.compile refuses to run under it)."""

    def __init__(self) -> None:
        super().__init__()
        self.ops = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.ops += 1
        return func(*args, **(kwargs or {}))


class StepCounts:
    """What one training step did, from a ``torch.profiler`` trace of it: host syncs
    (``SYNC_OPS`` called from Python; ``item`` counts once, not again as its
    ``_local_scalar_dense``) and, on a GPU, kernel and graph launches; for an eager step also
    the ATen ops it dispatched (``OpCounter``), the issue's count of its kernels."""

    def __init__(self, events, ops: int | None) -> None:
        names = collections.Counter(event.name for event in events)
        self.syncs = sum(
            1 for event in events if event.name in SYNC_OPS and not _inside_aten(event)
        )
        self.kernels = ops
        self.launches = sum(
            count
            for name, count in names.items()
            if name.startswith(("cudaLaunchKernel", "cuLaunchKernel", "cudaGraphLaunch"))
        )


class StepProbe(Callback):
    """Times the steps after ``skip`` (synchronizing only at the window's ends) and, with
    ``count``, profiles each of them on its own (``per_step``: global step, counts)."""

    def __init__(self, skip: int, count: bool = False) -> None:
        self.skip, self.count = skip, count
        self.start = self.end = 0.0
        self.per_step: list[tuple[int, StepCounts]] = []
        self._profiler: torch.profiler.profile | None = None

    def on_train_batch_start(self, trainer, module, batch, batch_idx) -> None:
        if batch_idx == self.skip:
            synchronize(module.device)
            self.start = time.perf_counter()
        if self.count and batch_idx >= self.skip:
            activities = [torch.profiler.ProfilerActivity.CPU]
            if module.device.type == "cuda":
                activities.append(torch.profiler.ProfilerActivity.CUDA)
            self._profiler = torch.profiler.profile(activities=activities)
            self._profiler.__enter__()
            self._ops = None if module.compiles else OpCounter()
            if self._ops is not None:
                self._ops.__enter__()

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx) -> None:
        if self._profiler is not None:
            synchronize(module.device)
            if self._ops is not None:
                self._ops.__exit__(None, None, None)
            self._profiler.__exit__(None, None, None)
            ops = None if self._ops is None else self._ops.ops
            self.per_step.append((trainer.global_step, StepCounts(self._profiler.events(), ops)))
            self._profiler = None

    def on_train_end(self, trainer, module) -> None:
        synchronize(module.device)
        self.end = time.perf_counter()


def fit(
    model: VRNNLRUModel,
    clips: torch.Tensor,
    batch_size: int,
    steps: int,
    skip: int,
    count: bool = False,
) -> StepProbe:
    """``steps`` training steps of ``model`` on ``clips`` through ``Trainer.fit``."""
    probe = StepProbe(skip, count)
    trainer = Trainer(
        accelerator=model.device.type,
        devices=1,
        max_steps=steps,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        log_every_n_steps=LOG_EVERY if count else TIMED_LOG_EVERY,
        callbacks=[probe],
        gradient_clip_val=10.0,
    )
    batches = ResidentBatches(clips, SequentialSampler(range(len(clips))), batch_size)
    trainer.fit(model, train_dataloaders=batches)
    return probe


def count_flops(model: VRNNLRUModel, clips: torch.Tensor, batch_size: int) -> float:
    """FLOPs of one forward + backward (matmuls and convolutions)."""
    frames = clips[:batch_size]
    counter = FlopCounterMode(display=False)
    with counter:
        noise = model.core.draw_noise(batch_size, frames.shape[1], frames.device)
        model.training_terms(frames, noise, torch.ones((), device=frames.device))[0].backward()
    model.zero_grad(set_to_none=True)
    return counter.get_total_flops()


def benchmark(
    name: str,
    device: torch.device,
    paths: list[str],
    batch_size: int,
    steps: int,
    rounds: int,
    frames: int,
) -> list[dict]:
    """One row per path for one model size and batch, measured in interleaved rounds."""
    sizes, _ = config_sizes(name)
    height, width = sizes.get("image_size", (64, 64))
    generator = torch.Generator().manual_seed(0)
    clips = torch.randint(
        0,
        256,
        (batch_size * (steps + 2), frames, height, width, 3),
        dtype=torch.uint8,
        generator=generator,
    ).to(device)
    models, first_fit, counts = {}, {}, {}
    for path in paths:
        torch.manual_seed(0)
        models[path] = VRNNLRUModel(**sizes, learning_rate=1e-4, **PATHS[path]).to(device)
        started = time.perf_counter()
        probe = fit(models[path], clips, batch_size, LOG_EVERY + 1, skip=1, count=True)
        first_fit[path] = time.perf_counter() - started
        counts[path] = probe.per_step  # steps 1..LOG_EVERY: the last one reads back
    flops = count_flops(models[paths[0]], clips, batch_size)
    seconds: dict[str, list[float]] = {path: [] for path in paths}
    for round_index in range(rounds):
        for path in paths if round_index % 2 == 0 else reversed(paths):
            probe = fit(models[path], clips, batch_size, steps + 2, skip=2)
            seconds[path].append((probe.end - probe.start) / steps)
    rows = []
    for path in paths:
        step = statistics.median(seconds[path])
        # The model reads back every LOG_EVERY steps and at the last step (LOG_EVERY + 1).
        plain = [counted for global_step, counted in counts[path][:-1] if global_step % LOG_EVERY]
        read_back = [
            counted for global_step, counted in counts[path] if not global_step % LOG_EVERY
        ]
        model = models[path]
        rows.append(
            {
                "model": name,
                "device": device.type,
                "path": path,
                "batch": batch_size,
                "compiled": model.compiles,
                "graphed": model.captures,
                "precision": "bf16-autocast" if model.uses_bf16 else "float32",
                "layout": "NHWC" if model.hparams.channels_last else "NCHW",
                "parameters": sum(p.numel() for p in model.parameters()),
                "gflop_per_step": flops / 1e9,
                "ms_per_step": step * 1e3,
                "sequences_per_s": batch_size / step,
                "syncs_per_step": statistics.mean(counted.syncs for counted in plain),
                "syncs_per_read_back": statistics.mean(counted.syncs for counted in read_back),
                "kernels_per_step": (
                    None
                    if model.compiles
                    else statistics.mean(counted.kernels for counted in plain)
                ),
                "launches_per_step": statistics.mean(counted.launches for counted in plain),
                "first_fit_s": first_fit[path],
                "achieved_gflops": flops / step / 1e9,
                "paper_run_hours": PAPER_SEQUENCES / (batch_size / step) / 3600,
            }
        )
    eager = next((row for row in rows if row["path"] == "eager"), None)
    for row in rows:
        row["vs_eager"] = row["sequences_per_s"] / eager["sequences_per_s"] if eager else None
    return rows


def print_table(rows: list[dict], header_note: str) -> None:
    header = (
        f"{'model':<11}{'path':<10}{'batch':>6}{'ms/step':>10}{'seq/s':>9}{'vs eager':>9}"
        f"{'syncs/step':>11}{'syncs/read-back':>16}{'ATen kernels':>13}{'launches':>9}"
        f"{'first fit (s)':>14}{'GFLOP/s':>9}{'20M seq (h)':>12}"
    )
    print(f"\n{header_note}\n{header}\n" + "-" * len(header))
    for r in rows:
        ratio = f"{r['vs_eager']:.2f}x" if r["vs_eager"] is not None else "-"
        kernels = "-" if r["kernels_per_step"] is None else f"{r['kernels_per_step']:,.0f}"
        print(
            f"{r['model']:<11}{r['path']:<10}{r['batch']:>6}{r['ms_per_step']:>10.1f}"
            f"{r['sequences_per_s']:>9.1f}{ratio:>9}{r['syncs_per_step']:>11.2f}"
            f"{r['syncs_per_read_back']:>16.2f}{kernels:>13}{r['launches_per_step']:>9,.0f}"
            f"{r['first_fit_s']:>14.1f}{r['achieved_gflops']:>9.1f}{r['paper_run_hours']:>12.1f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument("--models", nargs="+", choices=tuple(CONFIG_OF), default=list(CONFIG_OF))
    parser.add_argument(
        "--paths",
        nargs="+",
        choices=tuple(PATHS),
        default=None,
        help="default: reference, eager, compiled (and graphed on a GPU)",
    )
    parser.add_argument(
        "--batch-size",
        type=int,
        nargs="+",
        default=None,
        help="sequences per step (default: the config's, 8 quickstart / 10 paper)",
    )
    parser.add_argument(
        "--steps",
        type=int,
        default=None,
        help="timed steps per path and round (default: 3 on a CPU, 30 on a GPU)",
    )
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds per model")
    parser.add_argument("--frames", type=int, default=15, help="frames per sequence (paper: 15)")
    parser.add_argument(
        "--threads", type=int, default=None, help="CPU threads (torch.set_num_threads)"
    )
    parser.add_argument(
        "--json",
        type=Path,
        default=None,
        help='write {"machine": .., "paths": {"MODEL/PATH/bBATCH": {..}}} here',
    )
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            parser.error("--device cuda asked for, but torch.cuda.is_available() is False")
        torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
        machine = torch.cuda.get_device_name(device)
    else:
        machine = f"CPU, {torch.get_num_threads()} threads"
    paths = args.paths or ["reference", "eager", "compiled"] + (
        ["graphed"] if device.type == "cuda" else []
    )
    steps = args.steps or (30 if device.type == "cuda" else 3)
    rows = []
    for name in args.models:
        for batch_size in args.batch_size or [config_sizes(name)[1]]:
            rows += benchmark(name, device, paths, batch_size, steps, args.rounds, args.frames)
    print_table(
        rows,
        f"{machine}: T={args.frames} frames of 64x64, {args.rounds} interleaved "
        f"rounds of {steps} timed steps, medians; syncs counted with a read-back every {LOG_EVERY} steps, "
        f"timed with one every {TIMED_LOG_EVERY}",
    )
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "machine": machine,
                    "torch": torch.__version__,
                    "paths": {f"{r['model']}/{r['path']}/b{r['batch']}": r for r in rows},
                },
                indent=2,
            )
        )
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
