"""A store held against the plan (docs/architecture.md §5): each shard's index intact, the
planned concept, split, kinds or variants and seeds, the record spec's shapes and dtypes, the
current generator version and, in full, every record's checksum (``check_task``). ``generate``
keeps the shards that pass, ``verify`` lists those of a manifest's plan that fail, and a reader
refuses a split that holds one (``check_split``)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

from voe_lightning import specs
from voe_lightning.data.store.errors import CorruptShardError, ManifestError
from voe_lightning.data.store.layout import MANIFEST_NAME, SPLIT_RECORD_TYPE, SPLITS
from voe_lightning.data.store.manifest import manifest_seed_offset, read_manifest_or_error
from voe_lightning.data.store.plan import ShardTask, plan_shards, shard_meta
from voe_lightning.data.store.shards import check_shard, spec_layout
from voe_lightning.scenes.camera import VideoOptions


def verify(root: str | os.PathLike[str]) -> list[Path]:
    """Check every shard the manifest of ``root`` plans: intact index, the planned concept,
    split, kinds or variants and seeds per record, the record spec's shapes and dtypes, the
    current generator version and every record's checksum. Returns the paths of the missing,
    corrupt or foreign ones (empty when the store is intact); ``generate`` regenerates them."""
    return [path for path, _ in bad_shards(root, read_manifest_or_error(root))]


def bad_shards(
    root: str | os.PathLike[str],
    manifest: dict[str, Any],
    concepts: Sequence[str] | None = None,
    split: str | None = None,
    full: bool = True,
) -> list[tuple[Path, str]]:
    """(path, reason) of every shard of the manifest's plan that is missing, corrupt or foreign,
    of ``concepts`` and ``split`` where given (None: all); without ``full``, index only (what
    each shard is and holds, not every record's checksum: a reader checks those as it reads)."""
    try:
        tasks, video = manifest_plan(manifest)
    except ManifestError as error:
        raise ManifestError(f"{Path(root) / MANIFEST_NAME}: {error}") from error
    layouts = record_layouts(video)
    bad = []
    for task in tasks:
        if (concepts is not None and task.concept not in concepts) or split not in (
            None,
            task.split,
        ):
            continue
        try:
            check_task(Path(root), task, layouts, full)
        except CorruptShardError as error:
            bad.append((error.path, error.reason))
    return bad


def check_split(
    root: str | os.PathLike[str], manifest: dict[str, Any], concepts: Sequence[str], split: str
) -> None:
    """Refuse to read ``split`` of ``concepts`` unless every shard of it is the one the
    manifest plans (``bad_shards``, index only): a CorruptShardError names the first other one
    (another concept's, split's or version's, other seeds, missing) and what it is."""
    bad = bad_shards(root, manifest, concepts, split, full=False)
    if bad:
        raise CorruptShardError(*bad[0])


def manifest_plan(manifest: dict[str, Any]) -> tuple[list[ShardTask], VideoOptions]:
    """The shard plan and video options a manifest describes."""
    try:
        # Every setting stated: a default filled in would blame intact shards of another size.
        missing = [
            field.name for field in fields(VideoOptions) if field.name not in manifest["video"]
        ]
        if missing:
            raise KeyError(f"video.{missing[0]}")
        video = VideoOptions(**manifest["video"])
        concept_counts: dict[str, dict[str, dict[str, int]]] = {}
        for concept, entry in manifest["concepts"].items():
            canonical = {
                "train": specs.CLIP_KINDS_BY_CONCEPT[concept],
                "val": specs.STANDARD_VARIANTS[concept],
                "test": specs.STANDARD_VARIANTS[concept],
                "generalization": specs.GENERALIZATION_VARIANTS[concept],
            }
            concept_counts[concept] = {}
            for split in SPLITS:
                split_entry = entry["splits"][split]
                stored = split_entry["kinds" if split == "train" else "variants"]
                # JSON sorted the names; the plan interleaves them in their canonical order
                order = [n for n in canonical[split] if n in stored] + sorted(
                    set(stored) - set(canonical[split])
                )
                concept_counts[concept][split] = {name: stored[name] for name in order}
        return (
            plan_shards(concept_counts, manifest["shard_size"], manifest_seed_offset(manifest)),
            video,
        )
    except (KeyError, TypeError, AttributeError, ValueError) as error:
        raise ManifestError(
            f"the manifest describes no valid plan ({type(error).__name__}: {error}); "
            "regenerate with generate --overwrite"
        ) from error


def check_task(
    root: Path,
    task: ShardTask,
    layouts: dict[str, dict[str, tuple[str, tuple[int, ...]]]],
    full: bool = True,
) -> None:
    """Raise CorruptShardError naming the shard of ``task`` and why, unless it is intact and
    holds exactly the planned records (concept, split, names, seeds, shapes, generator)."""
    check_shard(
        task.path(root),
        task.seeds,
        full,
        shard_meta(task),
        layouts[SPLIT_RECORD_TYPE[task.split]],
    )


def record_layouts(video: VideoOptions) -> dict[str, dict[str, tuple[str, tuple[int, ...]]]]:
    """Per record type (clip, probe): the leaves, dtypes and shapes its shards must store."""
    size = (video.num_frames, video.height, video.width)
    return {
        "clip": spec_layout(specs.clip_spec(*size)),
        "probe": spec_layout(specs.probe_spec(*size)),
    }
