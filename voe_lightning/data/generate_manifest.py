"""The manifest a ``generate`` run writes (docs/architecture.md §5): its settings (format, video,
shard size, seed ranges and the probe splits' seed offset, vocabulary), generator and package versions, record specs and each
concept's splits; how it merges with the manifest already stored (refusing other settings unless
told to overwrite, which deletes the data they invalidate), and whether a stored manifest is the
one a request would write."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Any

from torchrl.data import Composite

import voe_lightning
from voe_lightning import specs
from voe_lightning.data import store, store_plan
from voe_lightning.data.store_plan import SEED_STARTS, manifest_seed_offset, seed_range
from voe_lightning.data.store_shards import FORMAT
from voe_lightning.scenes.camera import VideoOptions


class ManifestMismatchError(ValueError):
    """The root already holds a dataset generated with other settings."""


def _describe_spec(spec: Composite) -> dict[str, dict[str, object]]:
    """A JSON description of a record spec: per leaf its type, dtype, shape and bounds."""
    described: dict[str, dict[str, object]] = {}
    for key, leaf in spec.items(include_nested=True, leaves_only=True):
        key = key if isinstance(key, str) else "/".join(key)
        entry: dict[str, object] = {
            "type": type(leaf).__name__,
            "dtype": str(leaf.dtype),
            "shape": list(leaf.shape),
        }
        if hasattr(leaf.space, "low"):
            entry["low"], entry["high"] = leaf.space.low.min().item(), leaf.space.high.max().item()
        if hasattr(leaf.space, "n"):
            entry["n"] = int(leaf.space.n)
        described[key] = entry
    return described


def concept_entry(counts: dict[str, dict[str, int]], seed_offset: int = 0) -> dict[str, Any]:
    """A concept's manifest entry: per split its record type, count, seeds (``seed_range``,
    the probe splits' shifted by ``seed_offset``) and counts per kind or variant."""
    splits = {}
    for split in store.SPLITS:
        clips = store.SPLIT_RECORD_TYPE[split] == "clip"
        start, stop = seed_range(split, counts[split], seed_offset)
        splits[split] = {
            "record_type": store.SPLIT_RECORD_TYPE[split],
            "count": sum(counts[split].values()),
            "seed_start": start,
            "seed_stop": stop,
            "kinds" if clips else "variants": counts[split],
        }
    return {"splits": splits}


def _settings(video: VideoOptions, shard_size: int, seed_offset: int) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "video": dataclasses.asdict(video),
        "shard_size": shard_size,
        "seed_starts": SEED_STARTS,
        "seed_offset": seed_offset,
        "vocabulary": store.vocabulary(),
    }


_SETTING_KEYS = ("format", "video", "shard_size", "seed_starts", "seed_offset", "vocabulary")


def _stored_settings(manifest: dict[str, Any]) -> dict[str, Any]:
    """The settings a stored manifest records (a manifest before offsets: seed offset 0)."""
    return {
        **{k: manifest.get(k) for k in _SETTING_KEYS},
        "seed_offset": manifest_seed_offset(manifest),
    }


def _differences(old: object, new: object, prefix: str = "") -> list[str]:
    """Each leaf where ``old`` and ``new`` (nested dicts) differ, as "key.path: stored ..., asked
    ..."."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in sorted(set(old) | set(new)):
            out += _differences(old.get(key), new.get(key), f"{prefix}{key}.")
        return out
    return [] if old == new else [f"{prefix[:-1]}: stored {old!r}, asked {new!r}"]


def reconcile_manifest(
    root: Path,
    video: VideoOptions,
    shard_size: int,
    entries: dict[str, dict[str, Any]],
    overwrite: bool,
    seed_offset: int = 0,
) -> dict[str, Any]:
    """The manifest for this run: the stored one, extended with new concepts, or a new one.
    Refuses other settings for what is stored unless ``overwrite``, which deletes the data
    they invalidate (every concept if the video or shard settings changed). Read, merged and
    written under the root's manifest lock, so concurrent runs keep each other's concepts."""
    with store.manifest_lock(root):
        return _reconcile_locked(root, video, shard_size, entries, overwrite, seed_offset)


def _reconcile_locked(
    root: Path,
    video: VideoOptions,
    shard_size: int,
    entries: dict[str, dict[str, Any]],
    overwrite: bool,
    seed_offset: int,
) -> dict[str, Any]:
    """``reconcile_manifest``'s work, with the manifest lock held."""
    settings = _settings(video, shard_size, seed_offset)
    try:
        old = store.read_manifest(root)
    except store.ManifestError:
        if not overwrite:
            raise
        old = None  # replaced; the shards are checked against the new plan one by one
    if old is not None:
        setting_changes = _differences(_stored_settings(old), settings)
        changed = {c for c in entries if c in old["concepts"] and old["concepts"][c] != entries[c]}
        concept_changes = [
            d
            for c in sorted(changed)
            for d in _differences(old["concepts"][c], entries[c], f"{c}.")
        ]
        if setting_changes or concept_changes:
            if not overwrite:
                # follow from the per-kind counts and the seed offset
                derived = (".count:", ".seed_start:", ".seed_stop:")
                shown = [
                    d for d in setting_changes + concept_changes if not any(s in d for s in derived)
                ]
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
    if (
        old is not None
        and merged == old["concepts"]
        and old.get("generator_version") == store_plan.GENERATOR_VERSION
    ):
        return old
    manifest = {
        **settings,
        "package_version": voe_lightning.__version__,
        "generator_version": store_plan.GENERATOR_VERSION,
        "spec": {
            "clip": _describe_spec(specs.clip_spec(video.num_frames, video.height, video.width)),
            "probe": _describe_spec(specs.probe_spec(video.num_frames, video.height, video.width)),
        },
        "concepts": merged,
    }
    store.write_manifest(root, manifest)
    return manifest


def matches(
    manifest: dict[str, Any] | None,
    video: VideoOptions,
    shard_size: int,
    entries: dict[str, dict[str, Any]],
    seed_offset: int = 0,
) -> bool:
    """Whether the stored ``manifest`` is what a request of these settings and concept
    ``entries`` would write, at this ``GENERATOR_VERSION`` (None, no manifest, never is)."""
    if manifest is None or manifest.get("generator_version") != store_plan.GENERATOR_VERSION:
        return False
    if _differences(_stored_settings(manifest), _settings(video, shard_size, seed_offset)):
        return False
    return all(manifest["concepts"].get(c) == e for c, e in entries.items())
