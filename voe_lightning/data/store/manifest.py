"""The manifest, ``root/manifest.json`` (docs/architecture.md §5): the settings a store was
generated with (format, video, shard size, seed ranges and the probe splits' seed offset,
vocabulary), the generator and package versions, the record specs and each concept's splits.
Read, and checked to be a store's (``read_manifest``; ``read_manifest_or_error`` names the
command that makes a missing one); written by ``generate`` under the root's lock, merged with the
stored one, whose other settings it refuses unless told to overwrite, which deletes the data
they invalidate (``reconcile_manifest``); ``matches`` says whether the stored manifest is the
one a request would write, and ``check_fresh_offset`` whether a seed offset's probes are none
of those the store holds."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shlex
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

from filelock import FileLock
from torchrl.data import Composite

import voe_lightning
from voe_lightning import specs
from voe_lightning.data.store.errors import ManifestError, ManifestMismatchError
from voe_lightning.data.store.files import atomic_write
from voe_lightning.data.store.layout import (
    GENERATOR_VERSION,
    MANIFEST_NAME,
    PROBE_SPLITS,
    SEED_OFFSET_FOLDER,
    SEED_STARTS,
    SPLIT_RECORD_TYPE,
    SPLITS,
)
from voe_lightning.data.store.seeds import redraw_message, seed_range
from voe_lightning.data.store.shards import FORMAT
from voe_lightning.scenes.camera import VideoOptions

# --- reading ------------------------------------------------------------------------------------
#: Top-level manifest entries every reader relies on, and their JSON types.
MANIFEST_KEYS = {"video": dict, "shard_size": int, "concepts": dict}


def read_manifest(root: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The root's manifest, or None if there is none yet. Raises ManifestError naming the
    file when it is truncated, not JSON, or JSON of another shape."""
    path = Path(root) / MANIFEST_NAME
    fix = "delete it, or regenerate with generate --overwrite"
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (ValueError, UnicodeDecodeError) as error:
        raise ManifestError(f"unreadable manifest {path} (truncated?): {error}; {fix}") from error
    if not isinstance(manifest, dict):
        raise ManifestError(
            f"{path} holds a JSON {type(manifest).__name__ if manifest is not None else 'null'}, "
            f"not a voe_lightning manifest (an object); {fix}"
        )
    wrong = [
        f"{key} (missing)" if key not in manifest else f"{key} (a {type(manifest[key]).__name__})"
        for key, kind in MANIFEST_KEYS.items()
        if not isinstance(manifest.get(key), kind)
    ]
    if wrong:
        expected = ", ".join(f"{key}: {kind.__name__}" for key, kind in MANIFEST_KEYS.items())
        raise ManifestError(
            f"{path} is not a voe_lightning manifest: bad {', '.join(wrong)}; expected {expected}; {fix}"
        )
    return manifest


def read_manifest_or_error(root: str | os.PathLike[str]) -> dict[str, Any]:
    """The root's manifest; a FileNotFoundError naming the command that makes one if there is
    none: for a seed offset's folder, the one that draws its fresh probes (``draw_command``),
    not a store at offset 0 in the offset's place."""
    manifest = read_manifest(root)
    if manifest is None:
        offset = re.fullmatch(SEED_OFFSET_FOLDER.format(r"([1-9]\d{0,8})"), Path(root).name)
        command = (
            draw_command(Path(root).parent, int(offset[1]))
            if offset
            else shlex.join(["python", "-m", "voe_lightning", "generate", "--root", str(root)])
        )
        raise FileNotFoundError(
            f"no dataset at {root}: {Path(root) / MANIFEST_NAME} is missing "
            f"(create one with `{command}`)"
        )
    return manifest


def draw_command(
    root: str | os.PathLike[str],
    seed_offset: int,
    splits: Sequence[str] = PROBE_SPLITS,
    concepts: Sequence[str] = (),
) -> str:
    """The ``generate`` command that draws ``splits`` of ``concepts`` (default: those the store
    at ``root`` holds) fresh at ``seed_offset``, into ``root/seed_offset_<N>``: as many pairs per
    variant as the store holds of each, at its video size (generate's defaults where it records
    none), and no training clips or other probe split."""
    try:
        manifest = read_manifest(root) or {}
    except ManifestError:
        manifest = {}
    held = manifest.get("concepts", {})
    names = list(concepts or [c for c in specs.CONCEPTS if c in held])
    words = ["python", "-m", "voe_lightning", "generate", "--root", str(root)]
    words += ["--seed_offset", str(seed_offset), "--train_examples", "0"]
    if names:
        words += ["--concepts", f"[{', '.join(names)}]"]
    for split in PROBE_SPLITS:
        pairs = _held_pairs(held, names, split) if split in splits else 0
        words += [] if pairs is None else [f"--{split}_pairs", str(pairs)]
    video = manifest.get("video", {})
    for key in ("num_frames", "height", "width"):
        words += [f"--{key}", str(video[key])] if isinstance(video.get(key), int) else []
    return shlex.join(words)


def _held_pairs(held: dict[str, Any], concepts: Sequence[str], split: str) -> int | None:
    """The most pairs per variant a store's ``held`` concepts record of ``split`` among
    ``concepts``; None where they record none (an unreadable entry counts as none)."""
    counts = []
    for concept in concepts:
        try:
            counts += list(held[concept]["splits"][split]["variants"].values())
        except (KeyError, TypeError, AttributeError):
            continue
    return max((n for n in counts if isinstance(n, int)), default=None)


def manifest_seed_offset(manifest: dict[str, Any]) -> int:
    """The seed offset a manifest's probe splits were drawn at (0 where it records none, as
    every manifest before offsets)."""
    return cast(int, manifest.get("seed_offset", 0))


def vocabulary() -> dict[str, list[str]]:
    """The names that records' ``concept``, ``kind`` and ``variant`` indices decode to."""
    return {
        "concepts": list(specs.CONCEPTS),
        "clip_kinds": list(specs.CLIP_KINDS),
        "variants": list(specs.VARIANTS),
    }


def check_fresh_offset(
    root: str | os.PathLike[str], seed_offset: int, probes: Sequence[tuple[str, str]]
) -> None:
    """Refuse (ValueError) a seed offset whose ``probes`` (concept, probe split) would share
    seeds with those the store at ``root`` holds, the store they are drawn fresh to, naming
    the smallest offset that shares none. Nothing to check at offset 0 or with no store yet."""
    held = read_manifest(root) if seed_offset else None
    if held is None:
        return
    stops = {probe: _held_stop(root, held, *probe) - SEED_STARTS[probe[1]] for probe in probes}
    (concept, split), least = max(stops.items(), key=lambda item: item[1], default=(("", ""), 0))
    if seed_offset < least:
        where = (
            f"{root}'s {concept} {split} split holds seeds up to {SEED_STARTS[split] + least - 1:_}"
        )
        raise ValueError(redraw_message(seed_offset, least, where))


def _held_stop(
    root: str | os.PathLike[str], manifest: dict[str, Any], concept: str, split: str
) -> int:
    """One past the last seed of ``concept``'s ``split`` in the store ``manifest`` describes
    (the split's first seed when it holds none); a ManifestError when it records no split."""
    entry = manifest["concepts"].get(concept)
    if entry is None:
        return SEED_STARTS[split]
    try:
        variants = entry["splits"][split]["variants"]
        start, stop = seed_range(split, variants, manifest_seed_offset(manifest))
    except (KeyError, TypeError, AttributeError, ValueError) as error:
        raise ManifestError(
            f"{Path(root) / MANIFEST_NAME} records no valid {split} split of {concept} "
            f"({type(error).__name__}: {error}); regenerate with generate --overwrite"
        ) from error
    return stop if stop > start else SEED_STARTS[split]


# --- writing ------------------------------------------------------------------------------------
def concept_entry(counts: dict[str, dict[str, int]], seed_offset: int = 0) -> dict[str, Any]:
    """A concept's manifest entry: per split its record type, count, seeds (``seed_range``,
    the probe splits' shifted by ``seed_offset``) and counts per kind or variant."""
    splits = {}
    for split in SPLITS:
        clips = SPLIT_RECORD_TYPE[split] == "clip"
        start, stop = seed_range(split, counts[split], seed_offset)
        splits[split] = {
            "record_type": SPLIT_RECORD_TYPE[split],
            "count": sum(counts[split].values()),
            "seed_start": start,
            "seed_stop": stop,
            "kinds" if clips else "variants": counts[split],
        }
    return {"splits": splits}


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
    with manifest_lock(root):
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
        old = read_manifest(root)
    except ManifestError:
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
                    f"{root / MANIFEST_NAME} was generated with other settings:\n  "
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
        and old.get("generator_version") == GENERATOR_VERSION
    ):
        return old
    manifest = {
        **settings,
        "package_version": voe_lightning.__version__,
        "generator_version": GENERATOR_VERSION,
        "spec": {
            "clip": _describe_spec(specs.clip_spec(video.num_frames, video.height, video.width)),
            "probe": _describe_spec(specs.probe_spec(video.num_frames, video.height, video.width)),
        },
        "concepts": merged,
    }
    write_manifest(root, manifest)
    return manifest


def manifest_lock(root: str | os.PathLike[str]) -> FileLock:
    """The lock a writer holds from reading the root's manifest to writing it back, so two
    ``generate`` runs on one root (say, for two concepts) merge their entries instead of the
    last writer's replacing the other's."""
    Path(root).mkdir(parents=True, exist_ok=True)
    return FileLock(Path(root) / f".{MANIFEST_NAME}.lock")


def write_manifest(root: str | os.PathLike[str], manifest: dict[str, Any]) -> None:
    """Write the root's manifest atomically."""
    text = json.dumps(manifest, indent=2, sort_keys=True) + "\n"
    atomic_write(Path(root) / MANIFEST_NAME, [text.encode()])


def matches(
    manifest: dict[str, Any] | None,
    video: VideoOptions,
    shard_size: int,
    entries: dict[str, dict[str, Any]],
    seed_offset: int = 0,
) -> bool:
    """Whether the stored ``manifest`` is what a request of these settings and concept
    ``entries`` would write, at this ``GENERATOR_VERSION`` (None, no manifest, never is)."""
    if manifest is None or manifest.get("generator_version") != GENERATOR_VERSION:
        return False
    if _differences(_stored_settings(manifest), _settings(video, shard_size, seed_offset)):
        return False
    return all(manifest["concepts"].get(c) == e for c, e in entries.items())


def _settings(video: VideoOptions, shard_size: int, seed_offset: int) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "video": dataclasses.asdict(video),
        "shard_size": shard_size,
        "seed_starts": SEED_STARTS,
        "seed_offset": seed_offset,
        "vocabulary": vocabulary(),
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
