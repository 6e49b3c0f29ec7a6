"""A sharded, compressed, random-access store of clip and probe records
(docs/architecture.md §3, §5), as its users see it: the splits of every concept and where their
shards lie, the manifest that describes the whole, and each split as a map-style Dataset that
DataLoader workers read lazily (fork and spawn alike).

Layout: ``root/manifest.json`` and ``root/<concept>/<split>/shard-NNNNN.voe``. How a record
becomes bytes is ``store_codec``; the shard file, its index, checks and atomic writing are
``store_shards``; which records go into which shard is ``store_plan``.
"""

from __future__ import annotations

import json
import os
import re
import shlex
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from filelock import FileLock
from tensordict import TensorDict, TensorDictBase
from torch.utils.data import DataLoader, Dataset, Sampler

from voe_lightning import specs
from voe_lightning.data.store_shards import CorruptShardError, ShardReader, atomic_write

#: Splits of every concept: training clips, validation and test probes, generalization probes.
SPLITS: tuple[str, ...] = ("train", "val", "test", "generalization")
#: What each split holds.
SPLIT_RECORD_TYPE: dict[str, str] = {
    "train": "clip",
    "val": "probe",
    "test": "probe",
    "generalization": "probe",
}
#: The splits that hold probe pairs, which a seed offset draws fresh.
PROBE_SPLITS: tuple[str, ...] = tuple(s for s in SPLITS if SPLIT_RECORD_TYPE[s] == "probe")
#: Folder, under a store's root, of the store whose probe splits are shifted by a seed offset
#: (``store_plan.seed_offset_root``): a fresh test set beside the training data, never over it.
SEED_OFFSET_FOLDER = "seed_offset_{}"
MANIFEST_NAME = "manifest.json"
SHARD_SUFFIX = ".voe"
_MAX_OPEN_SHARDS = 32


# --- names and paths ----------------------------------------------------------------------------
def check_split(split: str) -> None:
    """Raise a ValueError listing the valid splits if ``split`` is not one of them."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; valid splits are: {', '.join(SPLITS)}")


def shard_path(root: str | os.PathLike[str], concept: str, split: str, index: int) -> Path:
    """Where shard ``index`` of a concept's split lives."""
    return Path(root) / concept / split / f"shard-{index:05d}{SHARD_SUFFIX}"


def shard_counts(count: int, shard_size: int) -> list[int]:
    """Records per shard when ``count`` records are cut into shards of ``shard_size``."""
    if shard_size < 1:
        raise ValueError(f"shard_size must be positive, got {shard_size}")
    full, rest = divmod(count, shard_size)
    return [shard_size] * full + ([rest] if rest else [])


# --- a split as a Dataset -----------------------------------------------------------------------
class SplitDataset(Dataset[TensorDict]):
    """A concept's split as a map-style Dataset of TensorDict records (``spec`` describes
    them). Safe to hand to DataLoader workers: each process opens shards lazily, keeping at
    most 32 open."""

    def __init__(
        self, root: str | os.PathLike[str], concept: str, split: str, manifest: dict[str, Any]
    ):
        self.root, self.concept, self.split = Path(root), concept, split
        entry = manifest["concepts"][concept]["splits"][split]
        self.record_type = entry["record_type"]
        video = manifest["video"]
        make_spec = specs.clip_spec if self.record_type == "clip" else specs.probe_spec
        self.spec = make_spec(video["num_frames"], video["height"], video["width"])
        self.shard_sizes = shard_counts(entry["count"], manifest["shard_size"])
        self.paths = [shard_path(root, concept, split, i) for i in range(len(self.shard_sizes))]
        self._starts = np.cumsum([0] + self.shard_sizes)
        self._shard_size = manifest["shard_size"]
        self._readers: OrderedDict[int, ShardReader] = OrderedDict()

    def __len__(self) -> int:
        return int(self._starts[-1])

    def _reader(self, shard: int) -> ShardReader:
        reader = self._readers.get(shard)
        if reader is None:
            reader = ShardReader(self.paths[shard])
            if len(reader) != self.shard_sizes[shard]:
                raise CorruptShardError(
                    reader.path,
                    f"holds {len(reader)} records, the manifest says {self.shard_sizes[shard]}",
                )
            self._readers[shard] = reader
            while len(self._readers) > _MAX_OPEN_SHARDS:
                self._readers.popitem(last=False)[1].close()
        else:
            self._readers.move_to_end(shard)
        return reader

    def __getitem__(self, index: int) -> TensorDict:
        index = int(index)
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} records of {self}")
        shard = index // self._shard_size
        return self._reader(shard)[index - int(self._starts[shard])]

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_readers"] = OrderedDict()
        return state

    def __repr__(self) -> str:
        return f"SplitDataset({str(self.root)!r}, {self.concept!r}, {self.split!r}, {len(self)} records)"


def collate(records: Sequence[TensorDictBase]) -> TensorDictBase:
    """DataLoader ``collate_fn`` for store records: stack them to batch_size [B] (torch's
    default collate does not know TensorDicts)."""
    return torch.stack(list(records))


def record_loader(
    dataset: Dataset[TensorDict], batch_size: int, num_workers: int = 0, **kwargs: Any
) -> DataLoader[TensorDict]:
    """A DataLoader of TensorDict record batches, as every DataModule serves them. Workers are
    persistent: torchrl makes multiprocessing spawn, and a spawned worker starts slowly."""
    return DataLoader(
        dataset,
        batch_size=batch_size,
        num_workers=num_workers,
        collate_fn=collate,
        persistent_workers=num_workers > 0,
        **kwargs,
    )


def probe_sampler(dataset: Dataset[TensorDict]) -> Sampler[int] | None:
    """Under DDP, each probe pair on exactly one rank, in order (Lightning's default
    DistributedSampler repeats pairs to even out the ranks, which would count them twice in
    the paired test); None (sequential) in a single process."""
    if not (torch.distributed.is_available() and torch.distributed.is_initialized()):
        return None
    # Imported here: generation workers import this module and need no Lightning.
    from lightning.pytorch.overrides.distributed import UnrepeatedDistributedSampler

    return UnrepeatedDistributedSampler(dataset, shuffle=False)


# --- manifest -----------------------------------------------------------------------------------
class ManifestError(ValueError):
    """A manifest that is unreadable or not a store's manifest; the message names the file."""


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


def vocabulary() -> dict[str, list[str]]:
    """The names that records' ``concept``, ``kind`` and ``variant`` indices decode to."""
    return {
        "concepts": list(specs.CONCEPTS),
        "clip_kinds": list(specs.CLIP_KINDS),
        "variants": list(specs.VARIANTS),
    }


def open_split(root: str | os.PathLike[str], concept: str, split: str) -> SplitDataset:
    """The records of ``concept``'s ``split`` (train, val, test or generalization) in the store
    at ``root``, as a torch Dataset of TensorDicts (batch them with ``collate_fn=collate``)."""
    specs.check_concept(concept)
    check_split(split)
    manifest = read_manifest_or_error(root)
    if manifest.get("vocabulary", vocabulary()) != vocabulary():
        raise ValueError(
            f"the store at {root} was written by voe_lightning {manifest.get('package_version')} "
            "with other concept/kind/variant names, so its indices would decode wrongly; "
            "regenerate it (generate --overwrite)"
        )
    stored = manifest["concepts"]
    if concept not in stored:
        raise ValueError(
            f"concept {concept!r} was not generated in {root}; it holds: {', '.join(stored) or 'none'}"
        )
    return SplitDataset(root, concept, split, manifest)
