"""Rendering the planned shards (docs/architecture.md §5): each shard's records, clips or probe
pairs, rendered by the scenes and written as one shard file, in ``workers`` processes; a record
that fails names its concept, split, kind or variant, seed and shard."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator
from pathlib import Path

from tensordict import TensorDict

from voe_lightning.data.store.layout import SPLIT_RECORD_TYPE
from voe_lightning.data.store.plan import ShardTask, shard_meta
from voe_lightning.data.store.shards import write_shard
from voe_lightning.data.store.workers import run_in_workers
from voe_lightning.scenes import generate_clip, generate_probe
from voe_lightning.scenes.camera import VideoOptions, draws_every_scene, size_advice
from voe_lightning.scenes.sampling import NoValidScene


def render_shards(
    root: Path, todo: list[ShardTask], video: VideoOptions, workers: int
) -> Iterator[tuple[int, int, int]]:
    """Render and write the shards of ``todo`` in ``workers`` processes
    (``workers.run_in_workers``), yielding (videos, records, bytes) as each is written. A worker
    that dies raises an error instead of hanging; on any error the shards already written stay
    and a rerun resumes."""
    yield from run_in_workers(
        _generate_shard_star, [(root, task, video) for task in todo], workers,
        died=f"a generation worker process died while writing {root} (its error is printed "
        "above); finished shards are kept: run generate again to resume",
    )  # fmt: skip


def _generate_shard_star(arguments: tuple[Path, ShardTask, VideoOptions]) -> tuple[int, int, int]:
    root, task, video = arguments
    return (task.num_videos, *generate_shard(root, task, video))


def generate_shard(
    root: str | os.PathLike[str], task: ShardTask, video: VideoOptions
) -> tuple[int, int]:
    """Render and write one shard; returns (records, bytes). Runs in a worker process."""
    records = []
    for name, seed in task.items:
        try:
            records.append(render_record(task.concept, task.split, name, seed, video))
        except (ValueError, RuntimeError) as error:
            # A ValueError is a setting the scene cannot render (solidity's num_frames): it
            # stays one, so the CLI prints it as the user's error, in one line; so does a
            # scene no draw of which fits a frame of a size outside those that work.
            small = isinstance(error, NoValidScene) and not draws_every_scene(video)
            kind = ValueError if isinstance(error, ValueError) or small else RuntimeError
            raise kind(
                f"rendering {task.concept} {task.split} {name} seed {seed} for {task.path(root)} "
                f"failed: {error}" + (f": {size_advice(video)}" if small else "")
            ) from error
    return len(records), write_shard(task.path(root), records, shard_meta(task))


def render_record(
    concept: str, split: str, name: str, seed: int, video: VideoOptions
) -> TensorDict:
    """Render one record of ``split``: a clip of kind ``name`` or a probe pair of variant ``name``."""
    options = dataclasses.asdict(video)
    if SPLIT_RECORD_TYPE[split] == "clip":
        return generate_clip(concept, name, seed, **options)
    return generate_probe(concept, name, seed, **options)
