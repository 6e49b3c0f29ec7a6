"""Generate the dataset store: per concept a train split of examples and controls and
validation, test and generalization probe splits from disjoint seed ranges, planned as a
deterministic list of shards that parallel worker processes render, resumably and in slices
(``--shard_index/--num_shards``) for cluster job arrays; with a ``seed_offset``, a fresh draw of
the probe splits into a store of their own (``store_plan.seed_offset_root``).
``python -m voe_lightning generate``."""

from __future__ import annotations

import dataclasses
import inspect
import os
import time
import warnings
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

from tensordict import TensorDict
from tqdm.auto import tqdm

from voe_lightning import specs
from voe_lightning.data import generate_manifest, store, store_shards, worker_pool
from voe_lightning.data.store_plan import (
    ShardTask,
    check_fresh_offset,
    check_seed_offset,
    check_task,
    drawn_probes,
    plan_shards,
    record_layouts,
    seed_offset_root,
    shard_meta,
    split_counts,
)
from voe_lightning.scenes import check_video, generate_clip, generate_probe
from voe_lightning.scenes.camera import VideoOptions, draws_every_scene, size_advice
from voe_lightning.scenes.sampling import NoValidScene

DEFAULT_SHARD_SIZE = 256
#: Paper scale (§A): 100,000 examples and 100,000 controls per concept, 2,000 validation and
#: 8,000 test pairs. The defaults are a tenth of the training set, where the paper still
#: found VOE effects (Figure 5).
DEFAULT_TRAIN_EXAMPLES = 10_000
DEFAULT_VAL_PAIRS = 500
DEFAULT_TEST_PAIRS = 2_000
DEFAULT_GENERALIZATION_PAIRS = 500


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


# --- rendering ----------------------------------------------------------------------------------
def render_record(
    concept: str, split: str, name: str, seed: int, video: VideoOptions
) -> TensorDict:
    """Render one record of ``split``: a clip of kind ``name`` or a probe pair of variant ``name``."""
    options = dataclasses.asdict(video)
    if store.SPLIT_RECORD_TYPE[split] == "clip":
        return generate_clip(concept, name, seed, **options)
    return generate_probe(concept, name, seed, **options)


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
    return len(records), store_shards.write_shard(task.path(root), records, shard_meta(task))


def _generate_shard_star(arguments: tuple[Path, ShardTask, VideoOptions]) -> tuple[int, int, int]:
    root, task, video = arguments
    return (task.num_videos, *generate_shard(root, task, video))


def _remove_stale_temporaries(path: Path) -> None:
    """Delete temporary files an interrupted write of ``path`` left behind: those whose
    process no longer runs on this host (``store_shards.remove_stale``); a running writer's
    (another ``generate`` on this root), or another host's, are left to it."""
    if path.parent.is_dir():
        store_shards.remove_stale(path.parent, path.name)


# --- entry points -------------------------------------------------------------------------------
@dataclass(frozen=True)
class GenerationPlan:
    """A checked generate request, planned once: where (the seed offset's store), which video
    size and shard size, each concept's manifest entry, the probe splits' seed offset, the
    splits asked for and every shard of them, in plan order (``store_plan.plan_shards``)."""

    root: Path
    video: VideoOptions
    shard_size: int
    entries: dict[str, dict[str, Any]]
    seed_offset: int
    splits: tuple[str, ...]
    tasks: tuple[ShardTask, ...]


def plan_generation(
    root: str | os.PathLike[str],
    concepts: Iterable[str] | str,
    train_examples: int | None,
    train_controls: int | None,
    val_pairs: int,
    test_pairs: int,
    generalization_pairs: int,
    shard_size: int,
    num_frames: int,
    height: int,
    width: int,
    seed_offset: int,
    splits: Iterable[str] = store.SPLITS,
) -> GenerationPlan:
    """Check generate's arguments (errors name the bad value and the valid choices) and plan
    the store they describe, once for the whole run: a ``train_examples`` of None is
    ``DEFAULT_TRAIN_EXAMPLES``, or none with a seed offset, whose store holds probes only."""
    checked_splits = _checked_splits(splits)
    check_seed_offset(seed_offset)
    names = _checked_concepts(concepts)
    counts = _checked_counts(
        root, train_examples, train_controls, val_pairs, test_pairs, generalization_pairs,
        seed_offset,
    )  # fmt: skip
    video = _checked_video(names, shard_size, num_frames, height, width, counts)
    _warn_of_shard_memory(video, shard_size)
    concept_counts = {concept: split_counts(concept, **counts) for concept in names}
    check_fresh_offset(root, seed_offset, drawn_probes(concept_counts))
    entries = {
        concept: generate_manifest.concept_entry(c, seed_offset)
        for concept, c in concept_counts.items()
    }
    tasks = plan_shards(concept_counts, shard_size, seed_offset)
    return GenerationPlan(
        root=seed_offset_root(root, seed_offset),
        video=video,
        shard_size=shard_size,
        entries=entries,
        seed_offset=seed_offset,
        splits=checked_splits,
        tasks=tuple(task for task in tasks if task.split in checked_splits),
    )


def _checked_concepts(concepts: Iterable[str] | str) -> tuple[str, ...]:
    """The concepts asked for, once each, in order; a ValueError names an unknown one."""
    names = (concepts,) if isinstance(concepts, str) else tuple(dict.fromkeys(concepts))
    if not names:
        raise ValueError(f"no concepts given; valid concepts are: {', '.join(specs.CONCEPTS)}")
    for concept in names:
        specs.check_concept(concept)
    return names


def _checked_counts(
    root: str | os.PathLike[str],
    train_examples: int | None,
    train_controls: int | None,
    val_pairs: int,
    test_pairs: int,
    generalization_pairs: int,
    seed_offset: int,
) -> dict[str, int]:
    """``split_counts``' arguments, each checked; training clips default to
    ``DEFAULT_TRAIN_EXAMPLES`` (none with a seed offset) and controls match examples 1:1."""
    if train_examples is None:
        train_examples = 0 if seed_offset else DEFAULT_TRAIN_EXAMPLES
    if train_controls is None:
        train_controls = train_examples  # matched 1:1 as in the paper
    if seed_offset and (train_examples or train_controls):
        raise ValueError(
            f"seed_offset {seed_offset} draws fresh probes only, into "
            f"{seed_offset_root(root, seed_offset)} (the training clips are not shifted and stay "
            f"in {root}); give train_examples 0 and train_controls 0, got {train_examples} and "
            f"{train_controls}"
        )
    counts = {
        "train_examples": train_examples,
        "train_controls": train_controls,
        "val_pairs": val_pairs,
        "test_pairs": test_pairs,
        "generalization_pairs": generalization_pairs,
    }
    for name, value in counts.items():
        if not isinstance(value, int) or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    return counts


def _checked_video(
    concepts: Sequence[str],
    shard_size: int,
    num_frames: int,
    height: int,
    width: int,
    counts: dict[str, int],
) -> VideoOptions:
    """The video options, checked with the shard size, and against every concept's scenes
    when probes are asked for (before a shard of any concept renders)."""
    if not isinstance(shard_size, int) or shard_size < 1:
        raise ValueError(f"shard_size must be a positive integer, got {shard_size!r}")
    if not isinstance(num_frames, int) or num_frames < 2:
        raise ValueError(
            f"num_frames must be an integer of at least 2 (a probe changes after "
            f"its first frame), got {num_frames!r}"
        )
    video = VideoOptions(num_frames=num_frames, height=height, width=width)
    if counts["val_pairs"] or counts["test_pairs"]:
        for concept in concepts:
            check_video(concept, num_frames=num_frames, height=height, width=width)
    return video


def _warn_of_shard_memory(video: VideoOptions, shard_size: int) -> None:
    """Warn when a shard, which a worker holds whole in memory while rendering it, would take
    more than a quarter of this machine's memory (frames and masks of both videos of a pair)."""
    pair_bytes = 2 * video.num_frames * video.height * video.width * (3 + 1)
    shard_bytes = shard_size * pair_bytes
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    if shard_bytes > memory / 4:
        warnings.warn(
            f"{video.height} x {video.width} x {video.num_frames} frames with shard_size "
            f"{shard_size} hold about {shard_bytes / 2**30:.1f} GiB per shard in each worker's "
            f"memory ({memory / 2**30:.0f} GiB here): lower shard_size, height or width",
            stacklevel=3,
        )


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
    splits: Iterable[str] = store.SPLITS,
    seed_offset: int = 0,
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
    seed_offset_<N>`` (``store_plan.seed_offset_root``, the summary's ``root``), which holds
    no training clips: a fresh test set that leaves the store at ``root`` untouched."""
    workers = _checked_workers(workers, shard_index, num_shards)
    plan = plan_generation(
        root, concepts, train_examples, train_controls, val_pairs, test_pairs,
        generalization_pairs, shard_size, num_frames, height, width, seed_offset, splits,
    )  # fmt: skip
    return _generate(plan, workers, shard_index, num_shards, overwrite, progress)


def _checked_workers(workers: int | None, shard_index: int, num_shards: int) -> int:
    """The worker processes to render with (None: all cores), checked with the slice
    ``shard_index`` of ``num_shards`` (errors name the bad value)."""
    if not isinstance(num_shards, int) or num_shards < 1:
        raise ValueError(f"num_shards must be a positive integer, got {num_shards!r}")
    if not isinstance(shard_index, int) or not 0 <= shard_index < num_shards:
        raise ValueError(f"shard_index must be in [0, {num_shards - 1}], got {shard_index!r}")
    workers = worker_pool.default_workers() if workers is None else workers
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
    generate_manifest.reconcile_manifest(
        root, plan.video, plan.shard_size, plan.entries, overwrite, plan.seed_offset
    )
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
        for videos, count, size in _run(root, todo, plan.video, workers):
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
        except store_shards.CorruptShardError as error:
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


def _run(root: Path, todo: list[ShardTask], video: VideoOptions,
         workers: int) -> Iterator[tuple[int, int, int]]:  # fmt: skip
    """Generate the shards of ``todo``, yielding (videos, records, bytes) as each is written,
    with ``workers`` processes (``worker_pool.run``). A worker that dies raises an error instead
    of hanging; on any error the shards already written stay and a rerun resumes."""
    yield from worker_pool.run(
        _generate_shard_star, [(root, task, video) for task in todo], workers,
        died=f"a generation worker process died while writing {root} (its error is printed "
        "above); finished shards are kept: run generate again to resume",
    )  # fmt: skip


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


def _checked_splits(splits: Iterable[str]) -> tuple[str, ...]:
    """``splits`` in the store's order, each checked (the error names the valid ones)."""
    wanted = set(splits)
    for split in sorted(wanted):
        store.check_split(split)
    return tuple(split for split in store.SPLITS if split in wanted)


def _is_complete(plan: GenerationPlan) -> bool:
    """Whether the store holds every planned shard, intact (checksums included: a corrupt
    record must be repaired before training, not met in the middle of it)."""
    manifest = store.read_manifest(plan.root)
    if not generate_manifest.matches(
        manifest, plan.video, plan.shard_size, plan.entries, plan.seed_offset
    ):
        return False
    layouts = record_layouts(plan.video)
    for task in plan.tasks:
        try:
            check_task(plan.root, task, layouts)
        except store_shards.CorruptShardError:
            return False
    return True


# --- command line -------------------------------------------------------------------------------
def generate(
    root: Path,
    concepts: list[specs.Concept] = list(get_args(specs.Concept)),  # noqa: B006, B008 (the CLI reads it; never mutated)
    train_examples: int | None = None,
    train_controls: int | None = None,
    val_pairs: int = DEFAULT_VAL_PAIRS,
    test_pairs: int = DEFAULT_TEST_PAIRS,
    generalization_pairs: int = DEFAULT_GENERALIZATION_PAIRS,
    shard_size: int = DEFAULT_SHARD_SIZE,
    workers: int | None = None,
    shard_index: int = 0,
    num_shards: int = 1,
    num_frames: int = specs.NUM_FRAMES,
    height: int = specs.HEIGHT,
    width: int = specs.WIDTH,
    overwrite: bool = False,
    contact_sheets: bool = False,
    progress: bool = True,
    seed_offset: int = 0,
) -> GenerationSummary:
    """Render the concepts' training clips and probe pairs into a sharded store.

    Resumable: shards that exist and verify are kept, missing or corrupt ones are rendered
    again. generate_dataset, printing what it did.

    Args:
        root: dataset folder.
        concepts: concepts to generate.
        train_examples: training examples per concept (default 10,000; none with a
            seed_offset).
        train_controls: training controls per concept, split evenly over its control kinds
            (default: as many as examples).
        val_pairs: validation probe pairs per concept and variant.
        test_pairs: test probe pairs per concept and variant.
        generalization_pairs: generalization probe pairs per concept and variant.
        shard_size: records per shard.
        workers: rendering processes (default: all cores).
        shard_index: this job's slice of the shards (cluster job arrays).
        num_shards: number of slices (the job array's size).
        num_frames: frames per video.
        height: frame height.
        width: frame width.
        overwrite: delete data generated with other settings instead of refusing.
        contact_sheets: write ROOT/contact_sheets/<concept>.png from the store at the end.
        progress: show a progress bar.
        seed_offset: shift the probe splits' seeds by this much (0 to 999,999,999 less the
            pairs per variant, and no less than ROOT's pairs per variant, whose seeds it would
            draw again) for a fresh test set no one has seen, written to its own store,
            ROOT/seed_offset_<N> (probes only; printed).
    """
    summary = generate_dataset(
        root, concepts, train_examples, train_controls, val_pairs=val_pairs,
        test_pairs=test_pairs, generalization_pairs=generalization_pairs,
        shard_size=shard_size, workers=workers, num_frames=num_frames, height=height, width=width,
        shard_index=shard_index, num_shards=num_shards, overwrite=overwrite, progress=progress,
        seed_offset=seed_offset,
    )  # fmt: skip
    print(
        f"{summary.root}: {summary.shards_generated} shards generated "
        f"({summary.records_generated} records, {summary.bytes_written / 1e6:.1f} MB), "
        f"{summary.shards_skipped} already complete, {summary.seconds:.1f} s"
    )
    if contact_sheets:
        from voe_lightning.data.contact_sheet import write_store_sheet

        for concept in dict.fromkeys(concepts):
            path = summary.root / "contact_sheets" / f"{concept}.png"
            write_store_sheet(summary.root, concept, path)
            print(f"wrote {path}")
    return summary
