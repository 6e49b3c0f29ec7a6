"""What a ``generate`` request makes (docs/architecture.md §5), planned once, before anything
renders (``plan_generation``): its arguments checked, each error naming the bad value and the
valid choices, and against the store a seed offset draws fresh to (``manifest.check_fresh_offset``); the
records of each concept's splits by clip kind or probe variant (``split_counts``), each
concept's manifest entry, and the deterministic list of shards (``plan_shards``): which records,
by kind or variant and seed, go into which shard, and what each shard records about itself to
count as done (``shard_meta``)."""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from voe_lightning import specs
from voe_lightning.data.store.layout import (
    GENERATOR_VERSION,
    SPLIT_RECORD_TYPE,
    SPLITS,
    check_split_name,
    shard_path,
)
from voe_lightning.data.store.manifest import check_fresh_offset, concept_entry
from voe_lightning.data.store.seeds import (
    check_seed_offset,
    seed_offset_root,
    seed_range,
    split_seeds,
)
from voe_lightning.scenes import check_video
from voe_lightning.scenes.camera import VideoOptions, check_duration, check_fps

DEFAULT_SHARD_SIZE = 256

#: Paper scale (§A): 100,000 examples and 100,000 controls per concept, 2,000 validation and
#: 8,000 test pairs. The defaults are a tenth of the training set, where the paper still
#: found VOE effects (Figure 5).
DEFAULT_TRAIN_EXAMPLES = 10_000
DEFAULT_VAL_PAIRS = 500
DEFAULT_TEST_PAIRS = 2_000
DEFAULT_GENERALIZATION_PAIRS = 500


@dataclass(frozen=True)
class ShardTask:
    """One shard of work: which records (clip kind or probe variant, and seed) go into it."""

    concept: str
    split: str
    index: int
    items: tuple[tuple[str, int], ...]
    seed_offset: int = 0

    def path(self, root: str | os.PathLike[str]) -> Path:
        return shard_path(root, self.concept, self.split, self.index)

    @property
    def seeds(self) -> list[int]:
        return [seed for _, seed in self.items]

    @property
    def num_videos(self) -> int:
        return len(self.items) * (1 if SPLIT_RECORD_TYPE[self.split] == "clip" else 2)


@dataclass(frozen=True)
class GenerationPlan:
    """A checked generate request, planned once: where (the seed offset's store), which video
    size and shard size, each concept's manifest entry, the probe splits' seed offset, the
    splits asked for and every shard of them, in plan order (``plan_shards``)."""

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
    splits: Iterable[str] = SPLITS,
    fps: float | None = None,
) -> GenerationPlan:
    """Check generate's arguments (errors name the bad value and the valid choices) and plan
    the store they describe, once for the whole run: a ``train_examples`` of None is
    ``DEFAULT_TRAIN_EXAMPLES``, or none with a seed offset, whose store holds probes only; an
    ``fps`` of None, 3 s clips (``VideoOptions``' default timing)."""
    if fps is not None:
        check_fps(fps)
    checked_splits = _checked_splits(splits)
    check_seed_offset(seed_offset)
    names = _checked_concepts(concepts)
    counts = _checked_counts(
        root, train_examples, train_controls, val_pairs, test_pairs, generalization_pairs,
        seed_offset,
    )  # fmt: skip
    video = _checked_video(names, shard_size, num_frames, height, width, counts, fps)
    _warn_of_shard_memory(video, shard_size)
    concept_counts = {concept: split_counts(concept, **counts) for concept in names}
    check_fresh_offset(root, seed_offset, drawn_probes(concept_counts))
    entries = {concept: concept_entry(c, seed_offset) for concept, c in concept_counts.items()}
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


def _checked_splits(splits: Iterable[str]) -> tuple[str, ...]:
    """``splits`` in the store's order, each checked (the error names the valid ones)."""
    wanted = set(splits)
    for split in sorted(wanted):
        check_split_name(split)
    return tuple(split for split in SPLITS if split in wanted)


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
    fps: float | None = None,
) -> VideoOptions:
    """The video options (``num_frames`` at ``fps``, or over 3 s when it is None), checked
    with the shard size, the clip's length against the scenes' timing, and against every
    concept's scenes when probes are asked for (before a shard of any concept renders)."""
    if not isinstance(shard_size, int) or shard_size < 1:
        raise ValueError(f"shard_size must be a positive integer, got {shard_size!r}")
    if not isinstance(num_frames, int) or num_frames < 2:
        raise ValueError(
            f"num_frames must be an integer of at least 2 (a probe changes after "
            f"its first frame), got {num_frames!r}"
        )
    if fps is None:
        video = VideoOptions(num_frames=num_frames, height=height, width=width)
    else:
        video = VideoOptions.at_fps(fps, num_frames, height, width)
        check_duration(video)
    if counts["val_pairs"] or counts["test_pairs"]:
        for concept in concepts:
            check_video(concept, **dataclasses.asdict(video))
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


def drawn_probes(
    concept_counts: Mapping[str, Mapping[str, Mapping[str, int]]],
) -> list[tuple[str, str]]:
    """The (concept, probe split) of every split that holds pairs in ``concept_counts``
    (``split_counts`` per concept)."""
    return [
        (concept, split)
        for concept, counts in concept_counts.items()
        for split, count in counts.items()
        if SPLIT_RECORD_TYPE[split] == "probe" and any(count.values())
    ]


def split_counts(
    concept: str,
    train_examples: int,
    train_controls: int,
    val_pairs: int,
    test_pairs: int,
    generalization_pairs: int,
) -> dict[str, dict[str, int]]:
    """Records per clip kind or probe variant in each split of ``concept`` (the ``*_pairs``
    counts are per probe variant)."""
    kinds = specs.CLIP_KINDS_BY_CONCEPT[concept]
    return {
        "train": {kinds[0]: train_examples, **split_evenly(train_controls, kinds[1:])},
        "val": {v: val_pairs for v in specs.STANDARD_VARIANTS[concept]},
        "test": {v: test_pairs for v in specs.STANDARD_VARIANTS[concept]},
        "generalization": {v: generalization_pairs for v in specs.GENERALIZATION_VARIANTS[concept]},
    }


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


def plan_shards(
    concept_counts: dict[str, dict[str, dict[str, int]]], shard_size: int, seed_offset: int = 0
) -> list[ShardTask]:
    """The deterministic list of every shard of the dataset, concept by concept, split by
    split; the probe splits' seeds shifted by ``seed_offset`` (``seed_range`` checks they stay
    in their split's range)."""
    tasks = []
    for concept, counts in concept_counts.items():
        for split in SPLITS:
            offset = 0 if SPLIT_RECORD_TYPE[split] == "clip" else seed_offset
            try:
                seed_range(split, counts[split], offset)
            except ValueError as error:
                raise ValueError(f"{concept}: {error}") from None
            names = interleave(counts[split])
            items = list(zip(names, split_seeds(split, names, offset)))
            for index, start in enumerate(range(0, len(items), shard_size)):
                tasks.append(
                    ShardTask(
                        concept, split, index, tuple(items[start : start + shard_size]), offset
                    )
                )
    return tasks


def shard_meta(task: ShardTask) -> dict[str, Any]:
    """What a shard of ``task`` records about itself, and must match to count as done."""
    return {
        "concept": task.concept,
        "split": task.split,
        "index": task.index,
        "record_type": SPLIT_RECORD_TYPE[task.split],
        "names": [name for name, _ in task.items],
        "generator_version": GENERATOR_VERSION,
        # Only where there is one: the shards of every store made before offsets stay valid.
        **({"seed_offset": task.seed_offset} if task.seed_offset else {}),
    }
