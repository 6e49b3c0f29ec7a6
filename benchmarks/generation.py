"""Generation throughput per concept on one core: videos per second (a probe pair counts as two
videos) through the production path (render, compress, write a shard), and bytes per video on
disk in the store. Run: ``python benchmarks/generation.py [--clips 60 --pairs 30]``."""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import torch

from voe_lightning import specs
from voe_lightning.data import store
from voe_lightning.data.store import render
from voe_lightning.data.store.codec import COMPRESSION_LEVEL
from voe_lightning.scenes.camera import VideoOptions
from voe_lightning.scenes.rendering import get_renderer


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def measure(concept: str, clips: int, pairs: int, video: VideoOptions, root: Path) -> dict:
    """Generate ``clips`` training clips (examples and controls 1:1) and ``pairs`` test probe
    pairs of ``concept`` as shards under ``root``; time each part and size the files."""
    variants = specs.STANDARD_VARIANTS[concept]
    counts = store.split_counts(
        concept, train_examples=clips // 2, train_controls=clips - clips // 2,
        val_pairs=0, test_pairs=-(-pairs // len(variants)),
        generalization_pairs=0,
    )  # fmt: skip
    tasks = store.plan_shards({concept: counts}, shard_size=max(clips, pairs, 1))
    result = {"concept": concept}
    for task in tasks:
        started, cpu_started = time.perf_counter(), time.process_time()
        count, size = render.generate_shard(root, task, video)
        seconds, cpu_seconds = time.perf_counter() - started, time.process_time() - cpu_started
        result[task.split] = {
            "records": count, "videos": task.num_videos, "seconds": seconds,
            "cpu_seconds": cpu_seconds, "bytes": size,
        }  # fmt: skip
    return result


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clips", type=int, default=60, help="training clips per concept")
    parser.add_argument("--pairs", type=int, default=30, help="probe pairs per concept")
    parser.add_argument("--concepts", nargs="+", default=list(specs.CONCEPTS))
    parser.add_argument("--num-frames", type=int, default=specs.NUM_FRAMES)
    parser.add_argument("--height", type=int, default=specs.HEIGHT)
    parser.add_argument("--width", type=int, default=specs.WIDTH)
    args = parser.parse_args(argv)
    for concept in args.concepts:
        specs.check_concept(concept)
    torch.set_num_threads(1)  # one core, as one generation worker uses
    video = VideoOptions(num_frames=args.num_frames, height=args.height, width=args.width)
    get_renderer(video.height, video.width)  # made once per worker; not part of the rate
    print(
        f"generation on one core of {_cpu_name()} ({os.cpu_count()} cores), "
        f"{video.num_frames} frames of {video.height}x{video.width}, MUJOCO_GL={os.environ.get('MUJOCO_GL')}, "
        f"{args.clips} clips + {args.pairs} probe pairs per concept, zstd level {COMPRESSION_LEVEL}"
    )
    # CPU time counts every thread of the process (software EGL may render with threads) and
    # is what a core delivers when the machine is not shared; wall time is what this run saw.
    header = (
        f"| {'concept':<18} | clips/s | pairs/s | videos/s/core | videos/CPU-s "
        "| bytes/video (clip) | bytes/video (probe) |"
    )
    print(header)
    print("|" + "|".join("-" * (len(part)) for part in header.split("|")[1:-1]) + "|")
    results = []
    with tempfile.TemporaryDirectory(prefix="voe_generation_benchmark_") as root:
        for concept in args.concepts:
            render.generate_shard(
                root, store.ShardTask(concept, "train", 999, (("example", 10**6),)), video
            )  # warm-up
            result = measure(concept, args.clips, args.pairs, video, Path(root))
            train, test = result["train"], result["test"]
            videos = train["videos"] + test["videos"]
            videos_per_second = videos / (train["seconds"] + test["seconds"])
            videos_per_cpu_second = videos / (train["cpu_seconds"] + test["cpu_seconds"])
            result["videos_per_second"] = videos_per_second
            result["videos_per_cpu_second"] = videos_per_cpu_second
            print(
                f"| {concept:<18} | {train['records'] / train['seconds']:7.1f} | "
                f"{test['records'] / test['seconds']:7.1f} | {videos_per_second:13.1f} | "
                f"{videos_per_cpu_second:12.1f} | "
                f"{train['bytes'] / train['videos']:18,.0f} | {test['bytes'] / test['videos']:19,.0f} |",
                flush=True,
            )
            results.append(result)
    total_videos = sum(r["train"]["videos"] + r["test"]["videos"] for r in results)
    total_bytes = sum(r["train"]["bytes"] + r["test"]["bytes"] for r in results)
    slowest = min(results, key=lambda r: r["videos_per_second"])
    print(
        f"mean bytes per video on disk: {total_bytes / total_videos:,.0f}; slowest concept: "
        f"{slowest['concept']} at {slowest['videos_per_second']:.1f} videos/s/core "
        f"({slowest['videos_per_cpu_second']:.1f} per CPU-second)"
    )
    return results


if __name__ == "__main__":
    main()
