"""Which seeds a split's records draw: clips count up from the split's first seed, probes per
variant from it plus a seed offset, each within the split's billion-wide range (``seed_range``,
``split_seeds``); a seed offset checked (``check_seed_offset``), and the store it draws into,
``root/seed_offset_<N>`` (``seed_offset_root``), so a fresh test set never touches the store a
model was trained and tuned on."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from voe_lightning.data.store.layout import (
    SEED_OFFSET_FOLDER,
    SEED_RANGE,
    SEED_STARTS,
    SPLIT_RECORD_TYPE,
)


def seed_range(split: str, counts: dict[str, int], seed_offset: int = 0) -> tuple[int, int]:
    """[start, stop) of the seeds ``split_seeds`` gives the records of ``split`` with these
    per kind or variant ``counts``: clips count up from the split's first seed, probes per
    variant from it plus ``seed_offset``. A ValueError naming the limit when they would leave
    the split's billion-wide range (into another split's seeds)."""
    clips = SPLIT_RECORD_TYPE[split] == "clip"
    start = SEED_STARTS[split] + (0 if clips else seed_offset)
    stop = start + (sum(counts.values()) if clips else max(counts.values(), default=0))
    limit = SEED_STARTS[split] + SEED_RANGE
    if stop > limit:
        raise ValueError(
            f"the {split} split would need seeds up to {stop - 1:_} (seed_offset "
            f"{0 if clips else seed_offset:_}, {stop - start:_} records"
            f"{'' if clips else ' per variant'}), past the last seed of its range, {limit - 1:_}: "
            f"seed_offset plus the count must be at most {SEED_RANGE:_}"
        )
    return start, stop


def split_seeds(split: str, names: Sequence[str], seed_offset: int = 0) -> list[int]:
    """The seed of each record of ``split`` (clip kinds or probe variants, in plan order):
    clips count up from the split's first seed; probes count up per variant from it plus
    ``seed_offset`` (a fresh draw of the probes), so the k-th pair of every variant has the
    same seed and the variants' pairs of one seed form a quadruplet (docs/architecture.md §4)."""
    if SPLIT_RECORD_TYPE[split] == "clip":
        return [SEED_STARTS[split] + i for i in range(len(names))]
    seen = dict.fromkeys(names, 0)
    seeds = []
    for name in names:
        seeds.append(SEED_STARTS[split] + seed_offset + seen[name])
        seen[name] += 1
    return seeds


def check_seed_offset(seed_offset: object, pairs: dict[str, int] | None = None) -> None:
    """Raise a ValueError unless ``seed_offset`` is an integer in [0, SEED_RANGE): a probe
    split's seeds start that far into its billion-wide range; with ``pairs`` (probe split ->
    pairs per variant, in the store at offset 0 and the offset's alike), unless each split's
    pairs fit in what is left (``seed_range``) and an offset other than 0 starts past them."""
    if (
        isinstance(seed_offset, bool)
        or not isinstance(seed_offset, int)
        or not 0 <= seed_offset < SEED_RANGE
    ):
        raise ValueError(
            f"seed_offset must be an integer in [0, {SEED_RANGE - 1:_}] (each "
            f"split's seeds span {SEED_RANGE:_}), got {seed_offset!r}"
        )
    for split, count in (pairs or {}).items():
        seed_range(split, {"pairs": count}, seed_offset)
    split, most = max((pairs or {}).items(), key=lambda item: item[1], default=("test", 0))
    if 0 < seed_offset < most:
        held = f"the {most:_} {split} pairs per variant read at offset 0"
        raise ValueError(redraw_message(seed_offset, most, held))


def redraw_message(seed_offset: int, least: int, held: str) -> str:
    """Why ``seed_offset`` is refused: its probes would be those of ``held`` again."""
    return (
        f"seed_offset {seed_offset:_} would draw probes already drawn ({held}; a probe "
        f"split's seeds count up from its start), not fresh ones: give a seed_offset of at "
        f"least {least:_}"
    )


def seed_offset_root(root: str | os.PathLike[str], seed_offset: int) -> Path:
    """The store holding the probe splits drawn at ``seed_offset``: ``root`` itself for 0,
    else its own store in ``root/seed_offset_<N>`` (probes only: the training clips are the
    root's), so a fresh test set never touches the store a model was trained and tuned on."""
    check_seed_offset(seed_offset)
    return Path(root) / SEED_OFFSET_FOLDER.format(seed_offset) if seed_offset else Path(root)


def store_root(data_arguments: Mapping[str, Any], split: str = "test") -> Path | None:
    """The store a DataModule with these init arguments reads ``split`` from: its ``root`` for
    the training clips, the store of its ``seed_offset`` (``seed_offset_root``) for the
    probes; None when they name no root. The one place a store root is derived."""
    if not data_arguments or data_arguments.get("root") is None:
        return None
    seed_offset = 0 if split == "train" else data_arguments.get("seed_offset") or 0
    return seed_offset_root(data_arguments["root"], seed_offset)
