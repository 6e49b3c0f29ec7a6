"""Generate the dataset store: per concept a train split of examples and controls and
validation, test and generalization probe splits from disjoint seed ranges, planned as a
deterministic list of shards that parallel worker processes render, resumably and in slices
(``--shard-index/--num-shards``) for cluster job arrays. ``python -m voe_lightning generate``."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import multiprocessing
import os
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

from tqdm.auto import tqdm

import voe_lightning
from voe_lightning import specs, store
from voe_lightning.scenes import generate_clip, generate_probe
from voe_lightning.scenes.base import VideoOptions

#: First seed of each split; the ranges are a billion wide, so splits never share a seed.
SEED_STARTS: dict[str, int] = {
    "train": 0,
    "val": 1_000_000_000,
    "test": 2_000_000_000,
    "generalization": 3_000_000_000,
}
SEED_RANGE = 1_000_000_000
DEFAULT_SHARD_SIZE = 256
#: Paper scale (§A): 100,000 examples and 100,000 controls per concept, 2,000 validation and
#: 8,000 test pairs. The defaults are a tenth of the training set, where the paper still
#: found VOE effects (Figure 5).
DEFAULT_TRAIN_EXAMPLES = 10_000
DEFAULT_VAL_PAIRS = 500
DEFAULT_TEST_PAIRS = 2_000
DEFAULT_GENERALIZATION_PAIRS = 500


class ManifestMismatchError(ValueError):
    """The root already holds a dataset generated with other settings."""


@dataclass(frozen=True)
class ShardTask:
    """One shard of work: which records (clip kind or probe variant, and seed) go into it."""

    concept: str
    split: str
    index: int
    items: tuple[tuple[str, int], ...]

    def path(self, root: str | os.PathLike) -> Path:
        return store.shard_path(root, self.concept, self.split, self.index)

    @property
    def seeds(self) -> list[int]:
        return [seed for _, seed in self.items]

    @property
    def num_videos(self) -> int:
        return len(self.items) * (1 if store.SPLIT_RECORD_TYPE[self.split] == "clip" else 2)


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


# --- planning -----------------------------------------------------------------------------------
def split_evenly(total: int, names: Sequence[str]) -> dict[str, int]:
    """``total`` shared among ``names`` as evenly as possible (the first ones get the rest)."""
    if not names:
        return {}
    share, rest = divmod(total, len(names))
    return {name: share + (i < rest) for i, name in enumerate(names)}


def interleave(counts: dict[str, int]) -> list[str]:
    """A sequence holding each name ``counts[name]`` times, spread evenly, so that every shard
    (and every prefix) holds all kinds in proportion."""
    keyed = [
        ((k + 0.5) / n, order, name)
        for order, (name, n) in enumerate(counts.items())
        for k in range(n)
    ]
    return [name for _, _, name in sorted(keyed)]


def split_counts(
    concept: str,
    train_examples: int,
    train_controls: int,
    val_pairs_per_variant: int,
    test_pairs_per_variant: int,
    generalization_pairs_per_variant: int,
) -> dict[str, dict[str, int]]:
    """Records per clip kind or probe variant in each split of ``concept``."""
    kinds = specs.CLIP_KINDS_BY_CONCEPT[concept]
    return {
        "train": {kinds[0]: train_examples, **split_evenly(train_controls, kinds[1:])},
        "val": {v: val_pairs_per_variant for v in specs.STANDARD_VARIANTS[concept]},
        "test": {v: test_pairs_per_variant for v in specs.STANDARD_VARIANTS[concept]},
        "generalization": {
            v: generalization_pairs_per_variant for v in specs.GENERALIZATION_VARIANTS[concept]
        },
    }


def plan_shards(concept_counts: dict[str, dict[str, dict[str, int]]], shard_size: int) -> list[ShardTask]:
    """The deterministic list of every shard of the dataset, concept by concept, split by split."""
    tasks = []
    for concept, counts in concept_counts.items():
        for split in store.SPLITS:
            names = interleave(counts[split])
            if len(names) > SEED_RANGE:
                raise ValueError(f"{split} of {concept} would need more than {SEED_RANGE} seeds")
            items = [(name, SEED_STARTS[split] + i) for i, name in enumerate(names)]
            for index, start in enumerate(range(0, len(items), shard_size)):
                tasks.append(ShardTask(concept, split, index, tuple(items[start : start + shard_size])))
    return tasks


def _describe_spec(spec) -> dict:
    """A JSON description of a record spec: per leaf its type, dtype, shape and bounds."""
    described = {}
    for key, leaf in spec.items(include_nested=True, leaves_only=True):
        key = key if isinstance(key, str) else "/".join(key)
        entry = {"type": type(leaf).__name__, "dtype": str(leaf.dtype), "shape": list(leaf.shape)}
        if hasattr(leaf.space, "low"):
            entry["low"], entry["high"] = leaf.space.low.min().item(), leaf.space.high.max().item()
        if hasattr(leaf.space, "n"):
            entry["n"] = int(leaf.space.n)
        described[key] = entry
    return described


def _concept_entry(counts: dict[str, dict[str, int]]) -> dict:
    splits = {}
    for split in store.SPLITS:
        count = sum(counts[split].values())
        key = "kinds" if store.SPLIT_RECORD_TYPE[split] == "clip" else "variants"
        splits[split] = {
            "record_type": store.SPLIT_RECORD_TYPE[split],
            "count": count,
            "seed_start": SEED_STARTS[split],
            "seed_stop": SEED_STARTS[split] + count,
            key: counts[split],
        }
    return {"splits": splits}


def _settings(video: VideoOptions, shard_size: int) -> dict:
    return {
        "format": store.FORMAT,
        "video": dataclasses.asdict(video),
        "shard_size": shard_size,
        "seed_starts": SEED_STARTS,
        "vocabulary": store.vocabulary(),
    }


_SETTING_KEYS = ("format", "video", "shard_size", "seed_starts", "vocabulary")


def _differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in sorted(set(old) | set(new)):
            out += _differences(old.get(key), new.get(key), f"{prefix}{key}.")
        return out
    return [] if old == new else [f"{prefix[:-1]}: stored {old!r}, asked {new!r}"]


def _reconcile_manifest(
    root: Path, video: VideoOptions, shard_size: int, entries: dict[str, dict], overwrite: bool
) -> dict:
    """The manifest for this run: the stored one, extended with new concepts, or a new one.
    Refuses other settings for what is stored unless ``overwrite``, which deletes the data
    they invalidate (every concept if the video or shard settings changed)."""
    settings = _settings(video, shard_size)
    old = store.read_manifest(root)
    if old is not None:
        setting_changes = _differences({k: old.get(k) for k in _SETTING_KEYS}, settings)
        changed = {
            c for c in entries if c in old["concepts"] and old["concepts"][c] != entries[c]
        }
        concept_changes = [
            d for c in sorted(changed) for d in _differences(old["concepts"][c], entries[c], f"{c}.")
        ]
        if setting_changes or concept_changes:
            if not overwrite:
                derived = (".count:", ".seed_stop:")  # follow from the per-kind counts
                shown = [d for d in setting_changes + concept_changes if not any(s in d for s in derived)]
                raise ManifestMismatchError(
                    f"{root / store.MANIFEST_NAME} was generated with other settings:\n  "
                    + "\n  ".join(shown or setting_changes + concept_changes)
                    + "\nUse another root, the same settings, or overwrite=True (--overwrite) "
                    "to delete the affected data and regenerate it."
                )
            doomed = set(old["concepts"]) if setting_changes else changed
            for concept in doomed & set(specs.CONCEPTS):
                shutil.rmtree(root / concept, ignore_errors=True)
            kept = {c: e for c, e in old["concepts"].items() if c not in doomed}
            old = {**old, **settings, "concepts": kept}
    merged = {**(old["concepts"] if old else {}), **entries}
    if old is not None and merged == old["concepts"]:
        return old
    manifest = {
        **settings,
        "package_version": voe_lightning.__version__,
        "spec": {
            "clip": _describe_spec(specs.clip_spec(video.num_frames, video.height, video.width)),
            "probe": _describe_spec(specs.probe_spec(video.num_frames, video.height, video.width)),
        },
        "concepts": merged,
    }
    store.write_manifest(root, manifest)
    return manifest


# --- rendering ----------------------------------------------------------------------------------
def render_record(concept: str, split: str, name: str, seed: int, video: VideoOptions):
    """Render one record of ``split``: a clip of kind ``name`` or a probe pair of variant ``name``."""
    options = dataclasses.asdict(video)
    if store.SPLIT_RECORD_TYPE[split] == "clip":
        return generate_clip(concept, name, seed, **options)
    return generate_probe(concept, name, seed, **options)


def generate_shard(root: str | os.PathLike, task: ShardTask, video: VideoOptions) -> tuple[int, int]:
    """Render and write one shard; returns (records, bytes). Runs in a worker process."""
    records = []
    for name, seed in task.items:
        try:
            records.append(render_record(task.concept, task.split, name, seed, video))
        except (ValueError, RuntimeError) as error:
            raise RuntimeError(
                f"rendering {task.concept} {task.split} {name} seed {seed} for {task.path(root)} "
                f"failed: {error}"
            ) from error
    meta = {
        "concept": task.concept,
        "split": task.split,
        "index": task.index,
        "record_type": store.SPLIT_RECORD_TYPE[task.split],
        "names": [name for name, _ in task.items],
    }
    return len(records), store.write_shard(task.path(root), records, meta)


def _generate_shard_star(arguments) -> tuple[int, int, int]:
    root, task, video = arguments
    return (task.num_videos, *generate_shard(root, task, video))


def _remove_stale_temporaries(path: Path) -> None:
    """Delete temporary files an interrupted write of ``path`` left behind."""
    if path.parent.is_dir():
        for temporary in path.parent.glob(f".{path.name}.*.tmp"):
            temporary.unlink(missing_ok=True)


def default_workers() -> int:
    """The number of cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


# --- entry points -------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Request:
    """A checked generate request: where, which video size, and the records of every split."""

    root: Path
    video: VideoOptions
    shard_size: int
    concept_counts: dict[str, dict[str, dict[str, int]]]
    entries: dict[str, dict]


def _prepare(
    root,
    concepts,
    train_examples,
    train_controls,
    val_pairs_per_variant,
    test_pairs_per_variant,
    generalization_pairs_per_variant,
    shard_size,
    num_frames,
    height,
    width,
) -> _Request:
    """Check generate's arguments (errors name the bad value and the valid choices)."""
    if isinstance(concepts, str):
        concepts = (concepts,)
    concepts = tuple(dict.fromkeys(concepts))
    if not concepts:
        raise ValueError(f"no concepts given; valid concepts are: {', '.join(specs.CONCEPTS)}")
    for concept in concepts:
        specs.check_concept(concept)
    if train_controls is None:
        train_controls = train_examples  # matched 1:1 as in the paper
    counts = {
        "train_examples": train_examples,
        "train_controls": train_controls,
        "val_pairs_per_variant": val_pairs_per_variant,
        "test_pairs_per_variant": test_pairs_per_variant,
        "generalization_pairs_per_variant": generalization_pairs_per_variant,
    }
    for name, value in counts.items():
        if not isinstance(value, int) or value < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    if not isinstance(shard_size, int) or shard_size < 1:
        raise ValueError(f"shard_size must be a positive integer, got {shard_size!r}")
    video = VideoOptions(num_frames=num_frames, height=height, width=width)
    concept_counts = {concept: split_counts(concept, **counts) for concept in concepts}
    entries = {concept: _concept_entry(c) for concept, c in concept_counts.items()}
    return _Request(Path(root), video, shard_size, concept_counts, entries)


def generate_dataset(
    root: str | os.PathLike,
    concepts: Iterable[str] = specs.CONCEPTS,
    train_examples: int = DEFAULT_TRAIN_EXAMPLES,
    train_controls: int | None = None,
    val_pairs_per_variant: int = DEFAULT_VAL_PAIRS,
    test_pairs_per_variant: int = DEFAULT_TEST_PAIRS,
    generalization_pairs_per_variant: int = DEFAULT_GENERALIZATION_PAIRS,
    shard_size: int = DEFAULT_SHARD_SIZE,
    workers: int | None = None,
    num_frames: int = specs.NUM_FRAMES,
    height: int = specs.HEIGHT,
    width: int = specs.WIDTH,
    shard_index: int = 0,
    num_shards: int = 1,
    overwrite: bool = False,
    progress: bool = True,
) -> GenerationSummary:
    """Generate (or complete, or repair) the store at ``root``. ``train_controls`` defaults to
    ``train_examples`` (1:1 as in the paper), split evenly over the concept's control kinds.
    Shards that exist and verify are kept; missing or corrupt ones are (re)rendered by
    ``workers`` processes (default: all cores). With ``num_shards`` > 1 only the shards
    ``shard_index, shard_index + num_shards, ...`` of the plan are made (a job array's slice).
    A root generated with other settings is refused unless ``overwrite``."""
    if not isinstance(num_shards, int) or num_shards < 1:
        raise ValueError(f"num_shards must be a positive integer, got {num_shards!r}")
    if not isinstance(shard_index, int) or not 0 <= shard_index < num_shards:
        raise ValueError(f"shard_index must be in [0, {num_shards - 1}], got {shard_index!r}")
    workers = default_workers() if workers is None else workers
    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    request = _prepare(
        root, concepts, train_examples, train_controls, val_pairs_per_variant,
        test_pairs_per_variant, generalization_pairs_per_variant, shard_size,
        num_frames, height, width,
    )  # fmt: skip
    root, video = request.root, request.video
    started = time.perf_counter()
    if root.exists() and not root.is_dir():
        raise NotADirectoryError(f"dataset root {root} exists and is not a directory")
    _reconcile_manifest(root, video, shard_size, request.entries, overwrite)
    tasks = plan_shards(request.concept_counts, shard_size)[shard_index::num_shards]
    todo = []
    for task in tasks:
        try:
            store.check_shard(task.path(root), task.seeds)
        except store.CorruptShardError:
            _remove_stale_temporaries(task.path(root))
            todo.append(task)
    total_videos = sum(task.num_videos for task in tasks)
    done_videos = total_videos - sum(task.num_videos for task in todo)
    records = written = 0
    bar = tqdm(
        total=total_videos,
        initial=done_videos,
        unit="video",
        desc=f"generate {root}" + (f" [{shard_index}/{num_shards}]" if num_shards > 1 else ""),
        disable=not progress,
        dynamic_ncols=True,
    )
    with bar:
        for videos, count, size in _run(root, todo, video, workers):
            records += count
            written += size
            bar.update(videos)
    return GenerationSummary(
        root, len(tasks), len(tasks) - len(todo), len(todo), records, written,
        time.perf_counter() - started,
    )  # fmt: skip


def _run(root: Path, todo: list[ShardTask], video: VideoOptions, workers: int):
    """Generate the shards of ``todo``, yielding (videos, records, bytes) as each is written:
    in this process for one worker, else in a pool of spawned processes (a fresh interpreter
    each: safe with EGL contexts and torch threads). A worker that dies raises an error
    instead of hanging; on any error the shards already written stay and a rerun resumes."""
    if workers == 1 or len(todo) <= 1:
        yield from (_generate_shard_star((root, task, video)) for task in todo)
        return
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(min(workers, len(todo)), context, initializer=_init_worker) as pool:
        futures = [pool.submit(_generate_shard_star, (root, task, video)) for task in todo]
        try:
            for future in as_completed(futures):
                yield future.result()
        except BrokenProcessPool as error:
            raise RuntimeError(
                f"a generation worker process died while writing {root} (its error is printed "
                "above); finished shards are kept: run generate again to resume"
            ) from error
        finally:
            for future in futures:
                future.cancel()  # shards not started are dropped; running ones finish


def _init_worker() -> None:
    """One thread per worker: rendering and physics are single-threaded; torch ops are tiny."""
    import torch

    torch.set_num_threads(1)


def ensure_dataset(root: str | os.PathLike, **options) -> GenerationSummary | None:
    """Make sure the store at ``root`` holds the dataset ``options`` (generate_dataset's
    arguments) describe: returns None at once when the manifest matches and every shard is
    present with an intact index, else generates what is missing. For DataModule.prepare_data."""
    bound = inspect.signature(generate_dataset).bind(root, **options)
    bound.apply_defaults()
    request = _prepare(**{k: bound.arguments[k] for k in inspect.signature(_prepare).parameters})
    if _is_complete(request):
        return None
    return generate_dataset(root, **options)


def _is_complete(request: "_Request") -> bool:
    manifest = store.read_manifest(request.root)
    if manifest is None:
        return False
    settings = _settings(request.video, request.shard_size)
    if _differences({k: manifest.get(k) for k in _SETTING_KEYS}, settings):
        return False
    if any(manifest["concepts"].get(c) != e for c, e in request.entries.items()):
        return False
    for task in plan_shards(request.concept_counts, request.shard_size):
        try:
            if store.read_index(task.path(request.root)).seeds != task.seeds:
                return False
        except store.CorruptShardError:
            return False
    return True


# --- command line -------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m voe_lightning generate",
        description="Render the five concepts' training clips and probe pairs into a sharded store "
        "(resumable; repairs missing or corrupt shards; --shard-index/--num-shards for job arrays).",
    )
    parser.add_argument("--root", required=True, type=Path, help="dataset folder")
    parser.add_argument(
        "--concepts", nargs="+", default=list(specs.CONCEPTS), metavar="CONCEPT",
        help=f"concepts to generate (default: all of {', '.join(specs.CONCEPTS)})",
    )  # fmt: skip
    parser.add_argument("--train-examples", type=int, default=DEFAULT_TRAIN_EXAMPLES)
    parser.add_argument(
        "--train-controls", type=int, default=None,
        help="controls per concept, split evenly over its control kinds (default: = examples)",
    )  # fmt: skip
    parser.add_argument("--val-pairs", type=int, default=DEFAULT_VAL_PAIRS, help="per probe variant")
    parser.add_argument("--test-pairs", type=int, default=DEFAULT_TEST_PAIRS, help="per probe variant")
    parser.add_argument(
        "--generalization-pairs", type=int, default=DEFAULT_GENERALIZATION_PAIRS,
        help="per generalization probe variant",
    )  # fmt: skip
    parser.add_argument("--shard-size", type=int, default=DEFAULT_SHARD_SIZE, help="records per shard")
    parser.add_argument("--workers", type=int, default=default_workers(), help="worker processes")
    parser.add_argument("--shard-index", type=int, default=0, help="this job's slice of the shards")
    parser.add_argument("--num-shards", type=int, default=1, help="number of slices (job array size)")
    parser.add_argument("--num-frames", type=int, default=specs.NUM_FRAMES)
    parser.add_argument("--height", type=int, default=specs.HEIGHT)
    parser.add_argument("--width", type=int, default=specs.WIDTH)
    parser.add_argument(
        "--overwrite", action="store_true",
        help="delete data generated with other settings instead of refusing",
    )  # fmt: skip
    parser.add_argument(
        "--contact-sheets", action="store_true",
        help="write ROOT/contact_sheets/<concept>.png from the store at the end",
    )  # fmt: skip
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> GenerationSummary:
    """``python -m voe_lightning generate ...``"""
    parser = build_parser()
    args = parser.parse_args(argv)
    for concept in args.concepts:
        if concept not in specs.CONCEPTS:
            parser.error(f"unknown concept {concept!r}; valid concepts are: {', '.join(specs.CONCEPTS)}")
    try:
        summary = generate_dataset(
            args.root,
            concepts=args.concepts,
            train_examples=args.train_examples,
            train_controls=args.train_controls,
            val_pairs_per_variant=args.val_pairs,
            test_pairs_per_variant=args.test_pairs,
            generalization_pairs_per_variant=args.generalization_pairs,
            shard_size=args.shard_size,
            workers=args.workers,
            num_frames=args.num_frames,
            height=args.height,
            width=args.width,
            shard_index=args.shard_index,
            num_shards=args.num_shards,
            overwrite=args.overwrite,
            progress=not args.no_progress,
        )
    except (ValueError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(2) from error
    print(
        f"{summary.root}: {summary.shards_generated} shards generated "
        f"({summary.records_generated} records, {summary.bytes_written / 1e6:.1f} MB), "
        f"{summary.shards_skipped} already complete, {summary.seconds:.1f} s"
    )
    if args.contact_sheets:
        from voe_lightning.contact_sheet import write_store_sheet

        for concept in dict.fromkeys(args.concepts):
            path = args.root / "contact_sheets" / f"{concept}.png"
            write_store_sheet(args.root, concept, path)
            print(f"wrote {path}")
    return summary


if __name__ == "__main__":
    main()
