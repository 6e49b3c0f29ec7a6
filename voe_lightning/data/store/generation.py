"""Generating a store (``generate_dataset``; ``ensure_dataset`` for a DataModule's
``prepare_data``), top-down: the request checked and planned (``plan``), the manifest reconciled
with the stored one (``manifest``), and the shards of this job's slice (``shard_index`` of
``num_shards``, for cluster job arrays) that are missing or do not match the plan (``verify``)
rendered by parallel worker processes (``render``). Resumable: a shard is written whole, so a
rerun keeps every shard finished; with a ``seed_offset``, a fresh draw of the probe splits into a
store of their own (``seeds.seed_offset_root``)."""

from __future__ import annotations

import inspect
import os
import time
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from voe_lightning import specs
from voe_lightning.data.store.errors import CorruptShardError
from voe_lightning.data.store.files import remove_stale
from voe_lightning.data.store.layout import SPLITS
from voe_lightning.data.store.manifest import matches, read_manifest, reconcile_manifest
from voe_lightning.data.store.plan import (
    DEFAULT_GENERALIZATION_PAIRS,
    DEFAULT_SHARD_SIZE,
    DEFAULT_TEST_PAIRS,
    DEFAULT_VAL_PAIRS,
    GenerationPlan,
    ShardTask,
    plan_generation,
)
from voe_lightning.data.store.render import render_shards
from voe_lightning.data.store.verify import check_task, record_layouts
from voe_lightning.data.store.workers import default_workers


@dataclass
class GenerationSummary:
    """What a generate call did."""

    root: Path
    shards_planned: int
    shards_skipped: int
    shards_generated: int
    records_generated: int
    bytes_written: int
    seconds: float


def generate_dataset(
    root: str | os.PathLike[str],
    concepts: Iterable[str] = specs.CONCEPTS,
    train_examples: int | None = None,
    train_controls: int | None = None,
    val_pairs: int = DEFAULT_VAL_PAIRS,
    test_pairs: int = DEFAULT_TEST_PAIRS,
    generalization_pairs: int = DEFAULT_GENERALIZATION_PAIRS,
    shard_size: int = DEFAULT_SHARD_SIZE,
    workers: int | None = None,
    num_frames: int = specs.NUM_FRAMES,
    height: int = specs.HEIGHT,
    width: int = specs.WIDTH,
    shard_index: int = 0,
    num_shards: int = 1,
    overwrite: bool = False,
    progress: bool = True,
    splits: Iterable[str] = SPLITS,
    seed_offset: int = 0,
    fps: float | None = None,
) -> GenerationSummary:
    """Generate (or complete, or repair) the store at ``root``. ``train_examples`` defaults to
    ``DEFAULT_TRAIN_EXAMPLES`` (none with a ``seed_offset``); ``train_controls`` to
    ``train_examples`` (1:1 as in the paper), split evenly over the concept's control kinds;
    ``val_pairs``, ``test_pairs`` and ``generalization_pairs`` count probe pairs per concept and
    variant (the DataModules' and ``generate``'s names).
    Shards that exist and verify are kept; missing or corrupt ones are (re)rendered by
    ``workers`` processes (default: all cores). With ``num_shards`` > 1 only the shards
    ``shard_index, shard_index + num_shards, ...`` of the plan are made (a job array's slice).
    Only the shards of ``splits`` are made (the manifest still plans every split, so a later
    run with all splits completes the store). A root generated with other settings is refused
    unless ``overwrite``. A ``seed_offset`` N shifts the probe splits' seeds by N (within
    each split's billion-wide range) and puts them in a store of their own, ``root/
    seed_offset_<N>`` (``seeds.seed_offset_root``, the summary's ``root``), which holds
    no training clips: a fresh test set that leaves the store at ``root`` untouched.
    ``num_frames`` are taken ``fps`` a second (``VideoOptions.at_fps``: frame k shows the scene
    at k / fps s); None, the default, spreads them over 3 s as every store before ``fps`` did
    (5 fps at the default 15 frames, and byte for byte the same videos)."""
    workers = _checked_workers(workers, shard_index, num_shards)
    plan = plan_generation(
        root, concepts, train_examples, train_controls, val_pairs, test_pairs,
        generalization_pairs, shard_size, num_frames, height, width, seed_offset, splits, fps,
    )  # fmt: skip
    return _generate(plan, workers, shard_index, num_shards, overwrite, progress)


def ensure_dataset(root: str | os.PathLike[str], **options: Any) -> GenerationSummary | None:
    """Make sure the store at ``root`` holds the dataset ``options`` (generate_dataset's
    arguments) describe: returns None at once when the manifest matches and every shard of
    ``splits`` is present with an intact index, else says which splits it generates where and
    generates what is missing, from the same plan. For DataModule.prepare_data."""
    arguments = inspect.signature(generate_dataset).bind(root, **options)
    arguments.apply_defaults()
    given = arguments.arguments
    plan = plan_generation(**{k: given[k] for k in inspect.signature(plan_generation).parameters})
    if _is_complete(plan):
        return None
    print(
        f"generating the {', '.join(plan.splits)} split{'s' if len(plan.splits) > 1 else ''} "
        f"of {', '.join(plan.entries)} under {plan.root} (missing or incomplete there)"
    )
    workers = _checked_workers(given["workers"], given["shard_index"], given["num_shards"])
    return _generate(
        plan, workers, given["shard_index"], given["num_shards"], given["overwrite"],
        given["progress"],
    )  # fmt: skip


def _checked_workers(workers: int | None, shard_index: int, num_shards: int) -> int:
    """The worker processes to render with (None: all cores), checked with the slice
    ``shard_index`` of ``num_shards`` (errors name the bad value)."""
    if not isinstance(num_shards, int) or num_shards < 1:
        raise ValueError(f"num_shards must be a positive integer, got {num_shards!r}")
    if not isinstance(shard_index, int) or not 0 <= shard_index < num_shards:
        raise ValueError(f"shard_index must be in [0, {num_shards - 1}], got {shard_index!r}")
    workers = default_workers() if workers is None else workers
    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    return workers


def _generate(
    plan: GenerationPlan,
    workers: int,
    shard_index: int,
    num_shards: int,
    overwrite: bool,
    progress: bool,
) -> GenerationSummary:
    """Render the shards of ``plan``'s slice ``shard_index`` of ``num_shards`` that are
    missing or corrupt, after reconciling the manifest (``generate_dataset``)."""
    root = plan.root
    started = time.perf_counter()
    if root.exists() and not root.is_dir():
        raise NotADirectoryError(f"dataset root {root} exists and is not a directory")
    reconcile_manifest(root, plan.video, plan.shard_size, plan.entries, overwrite, plan.seed_offset)
    tasks = plan.tasks[shard_index::num_shards]
    todo = _shards_to_render(plan, tasks)
    total_videos = sum(task.num_videos for task in tasks)
    records = written = 0
    bar = tqdm(
        total=total_videos,
        initial=total_videos - sum(task.num_videos for task in todo),
        unit="video",
        desc=f"generate {root}" + (f" [{shard_index}/{num_shards}]" if num_shards > 1 else ""),
        disable=not progress,
        dynamic_ncols=True,
    )
    with bar:
        for videos, count, size in render_shards(root, todo, plan.video, workers):
            records += count
            written += size
            bar.update(videos)
    return GenerationSummary(
        root, len(tasks), len(tasks) - len(todo), len(todo), records, written,
        time.perf_counter() - started,
    )  # fmt: skip


def _shards_to_render(plan: GenerationPlan, tasks: Sequence[ShardTask]) -> list[ShardTask]:
    """The shards of ``tasks`` missing or not matching the plan in ``plan.root`` (their stale
    temporaries deleted), warning of those it replaces."""
    layouts = record_layouts(plan.video)
    todo, replaced = [], []
    for task in tasks:
        try:
            check_task(plan.root, task, layouts)
        except CorruptShardError as error:
            _remove_stale_temporaries(task.path(plan.root))
            todo.append(task)
            if error.reason != "missing":
                replaced.append(f"{error.path}: {error.reason}")
    if replaced:
        warnings.warn(
            f"regenerating {len(replaced)} shard(s) of {plan.root} that do not match the plan:"
            "\n  " + "\n  ".join(replaced[:20]) + ("\n  ..." if len(replaced) > 20 else ""),
            stacklevel=4,
        )
    return todo


def _remove_stale_temporaries(path: Path) -> None:
    """Delete temporary files an interrupted write of ``path`` left behind: those whose
    process no longer runs on this host (``files.remove_stale``); a running writer's
    (another ``generate`` on this root), or another host's, are left to it."""
    if path.parent.is_dir():
        remove_stale(path.parent, path.name)


def _is_complete(plan: GenerationPlan) -> bool:
    """Whether the store holds every planned shard, intact (checksums included: a corrupt
    record must be repaired before training, not met in the middle of it)."""
    manifest = read_manifest(plan.root)
    if not matches(manifest, plan.video, plan.shard_size, plan.entries, plan.seed_offset):
        return False
    layouts = record_layouts(plan.video)
    for task in plan.tasks:
        try:
            check_task(plan.root, task, layouts)
        except CorruptShardError:
            return False
    return True
