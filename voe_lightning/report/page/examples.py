"""The example quadruplets a report's page shows: per concept, the quadruplet whose D is the
median of its quadruplets' (``choose_quadruplets``), its four videos A, AB, B and BA read back
from the probe store summary.json names and saved small into ``examples/<concept>.npz``
(``save_examples``), so the page can be rebuilt from the report folder alone
(``read_examples``)."""

from __future__ import annotations

import io
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from voe_lightning import specs
from voe_lightning.data import store
from voe_lightning.data.store import write_whole
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.summary_file import read_summary
from voe_lightning.stats.verdicts import quadruplets

#: The report's folder of example videos.
EXAMPLES = "examples"
#: A quadruplet's videos: each half's consistent, then inconsistent video.
VIDEOS = ("A", "AB", "B", "BA")
#: The largest side, in pixels, of a saved frame (larger frames are shrunk to it).
MAX_SIDE = 64


@dataclass(frozen=True)
class Quadruplet:
    """One quadruplet of a report: its concept, its two halves' variants (first: A, AB;
    second: B, BA), its seed, the index of each half's pair in ``PairResults`` and its D's
    rank among the concept's ``count`` quadruplets (the median's)."""

    concept: str
    variants: tuple[str, str]
    seed: int
    pairs: tuple[int, int]
    count: int


@dataclass(frozen=True)
class ExampleVideos:
    """A saved quadruplet (``Quadruplet``'s concept, variants, seed and count) and its four
    videos' frames, uint8 [T, H, W, 3] by name in ``VIDEOS``."""

    concept: str
    variants: tuple[str, str]
    seed: int
    count: int
    frames: Mapping[str, np.ndarray]


def choose_quadruplets(results: PairResults) -> list[Quadruplet]:
    """Per concept (its first quadruplet row: unchangeableness' position change), the
    quadruplet whose D = d(first half) + d(second half) is the median one (the lower of two)."""
    relative = results.relative_surprise
    chosen: dict[str, Quadruplet] = {}
    for concept, _, first, second in quadruplets(
        results.concept, results.variant, results.seed.tolist()
    ):
        if concept in chosen:
            continue
        total = relative[first] + relative[second]
        order = np.lexsort((results.seed[first], total))
        middle = int(order[(len(order) - 1) // 2])
        first_pair, second_pair = int(first[middle]), int(second[middle])
        chosen[concept] = Quadruplet(
            concept,
            (results.variant[first_pair], results.variant[second_pair]),
            int(results.seed[first_pair]),
            (first_pair, second_pair),
            len(order),
        )
    return list(chosen.values())


def _split_index(root: Path, concept: str, split: str, variant: str, seed: int) -> int:
    """The index in ``store.open_split`` of the pair of ``variant`` and ``seed`` (the store's
    shard plan, ``store.manifest_plan``, orders them)."""
    tasks, _ = store.manifest_plan(store.read_manifest_or_error(root))
    items = [
        item
        for task in tasks
        if (task.concept, task.split) == (concept, split)
        for item in task.items
    ]
    try:
        return items.index((variant, seed))
    except ValueError:
        raise ValueError(f"{root} holds no {concept}/{variant} pair of seed {seed}") from None


def _pair_frames(root: Path, concept: str, split: str, variant: str, seed: int) -> list[np.ndarray]:
    """The consistent and inconsistent frames of the store's pair of ``variant`` and ``seed``."""
    record = store.open_split(root, concept, split)[
        _split_index(root, concept, split, variant, seed)
    ]
    stored = (specs.VARIANTS[int(record["variant"])], int(record["seed"]))
    if stored != (variant, seed):
        raise ValueError(f"{root}'s {concept} record for {variant}/{seed} holds {stored}")
    return [_small(record[side, "frames"].numpy()) for side in ("consistent", "inconsistent")]


def _small(frames: np.ndarray) -> np.ndarray:
    """``frames`` [T, H, W, 3] shrunk (box filter) to fit ``MAX_SIDE`` if larger."""
    height, width = frames.shape[1:3]
    scale = MAX_SIDE / max(height, width)
    if scale >= 1:
        return frames
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    return np.stack(
        [np.asarray(Image.fromarray(f).resize(size, Image.Resampling.BOX)) for f in frames]
    )


def save_examples(report_dir: str | Path) -> list[Path]:
    """Write ``examples/<concept>.npz`` into ``report_dir`` for each ``choose_quadruplets``
    quadruplet of its pairs.csv, its frames read from the probe store its summary.json names
    (``source.probe_root``, split ``source.probe_split``); the paths written. A report naming
    no store (an external benchmark's) gets none; a store that cannot be read, a warning."""
    report_dir = Path(report_dir)
    source = read_summary(report_dir).get("source") or {}
    if not source.get("probe_root"):
        return []
    root, split = Path(source["probe_root"]), source.get("probe_split") or "test"
    files: dict[str | os.PathLike[str], bytes] = {}
    try:
        results = PairResults.from_csv(report_dir / "pairs.csv")
        for example in choose_quadruplets(results):
            frames = [
                video
                for variant in example.variants
                for video in _pair_frames(root, example.concept, split, variant, example.seed)
            ]
            files[report_dir / EXAMPLES / f"{example.concept}.npz"] = _npz(example, frames)
    except (OSError, ValueError, KeyError, IndexError) as error:
        warnings.warn(f"no example videos in {report_dir}: {error}", stacklevel=2)
        return []
    (report_dir / EXAMPLES).mkdir(exist_ok=True)
    write_whole(files)
    return sorted(Path(path) for path in files)


def _npz(example: Quadruplet, frames: list[np.ndarray]) -> bytes:
    """The .npz of a quadruplet: its videos by name, concept, variants, seed and count."""
    arrays: dict[str, Any] = {
        "concept": np.array(example.concept),
        "variants": np.array(example.variants),
        "seed": np.array(example.seed, dtype=np.int64),
        "count": np.array(example.count, dtype=np.int64),
        **dict(zip(VIDEOS, frames)),
    }
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def read_examples(report_dir: str | Path) -> list[ExampleVideos]:
    """The quadruplets saved in ``report_dir/examples/``, in ``specs.CONCEPTS`` order."""
    found = []
    for path in sorted((Path(report_dir) / EXAMPLES).glob("*.npz")):
        with np.load(path, allow_pickle=False) as saved:
            found.append(_example(saved))
    order = {concept: i for i, concept in enumerate(specs.CONCEPTS)}
    return sorted(found, key=lambda e: (order.get(e.concept, len(order)), e.concept))


def _example(saved: Any) -> ExampleVideos:
    """An ``ExampleVideos`` of an opened .npz."""
    first, second = (str(v) for v in saved["variants"])
    return ExampleVideos(
        str(saved["concept"]),
        (first, second),
        int(saved["seed"]),
        int(saved["count"]),
        {name: saved[name] for name in VIDEOS},
    )
