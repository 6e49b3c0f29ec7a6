"""``python -m voe_lightning export``: a probe split of a store written in a format other
harnesses read (IntPhys 2, IntPhys, WebDataset), with its manifest."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from voe_lightning.benchmarks.intphys.export import write_intphys
from voe_lightning.benchmarks.intphys2.export import write_intphys2
from voe_lightning.export.manifest import (
    ExportFolder,
    Progress,
    Written,
    build_manifest,
    check_out,
    citation,
    staged,
    write_manifest,
)
from voe_lightning.export.probes import ProbeSource, open_fresh_probes
from voe_lightning.export.webdataset import write_webdataset

#: The formats, in ``--help``'s order.
FORMATS: tuple[str, ...] = ("intphys2", "intphys", "webdataset")
DEFAULT_SHARD_SIZE = 256


def writer(
    export_format: str, shard_size: int
) -> Callable[[ProbeSource, ExportFolder, Progress], Written]:
    """The function that writes ``export_format``; a ValueError names a bad format or shard
    size and the valid ones."""
    if export_format not in FORMATS:
        raise ValueError(
            f"unknown format {export_format!r}; valid formats are: {', '.join(FORMATS)}"
        )
    if isinstance(shard_size, bool) or not isinstance(shard_size, int) or shard_size < 1:
        raise ValueError(f"shard_size must be a positive integer, got {shard_size!r}")
    if export_format == "webdataset":
        return functools.partial(write_webdataset, shard_size=shard_size)
    return write_intphys2 if export_format == "intphys2" else write_intphys


def export(
    root: Path,
    format: str,
    out: Path,
    split: str = "test",
    concepts: list[str] | None = None,
    seed_offset: int = 0,
    shard_size: int = DEFAULT_SHARD_SIZE,
    progress: bool = True,
) -> dict[str, Any]:
    """Write a probe split of a store in another benchmark's format, with a manifest.

    intphys2: per concept, CONCEPT/Main/Videos/NAME.mp4 and CONCEPT/Main/metadata.csv (IntPhys
    2's columns; a quadruplet is a scene). intphys: per concept, IntPhys' labelled dev layout,
    CONCEPT/dev/BLOCK/SCENE/MOVIE/scene/scene_001.png ... and status.json (quadruplets only).
    webdataset: SPLIT-000000.tar ..., one sample per pair (KEY.json and every record leaf as
    KEY.LEAF.npy). OUT/manifest.json gives the generator version, split, seeds and seed
    offset, the quadruplets (which videos, which consistent, which concept) and each file's
    SHA-256; returns it.

    Args:
        root: dataset folder (a generated store).
        format: intphys2, intphys or webdataset.
        out: folder to write (new or empty).
        split: probe split to export: val, test or generalization.
        concepts: concepts to export (default: every concept in the store).
        seed_offset: export the fresh probes generate --seed_offset N drew (read from
            ROOT/seed_offset_N, which must record that offset and share no seed with ROOT).
        shard_size: pairs per tar shard (webdataset).
        progress: show a progress bar.
    """
    write = writer(format, shard_size)
    out = Path(out)
    check_out(out)
    source = open_fresh_probes(root, split, concepts, seed_offset)
    bar = tqdm(
        total=source.num_videos,
        unit="video",
        desc=f"export {format} {out}",
        disable=not progress,
        dynamic_ncols=True,
    )
    with staged(out) as folder, bar:
        written = write(source, folder, bar)
        manifest = build_manifest(source, format, written, folder.files)
        write_manifest(folder, manifest)
    print(
        f"{out}: {len(manifest['quadruplets'])} quadruplets and {len(manifest['pairs'])} lone "
        f"pairs of {source.root}'s {split} split as {format} ({len(manifest['files'])} files"
        + (f"; {len(written.left_out)} lone pairs left out" if written.left_out else "")
        + f"); cite as: {citation(source)}"
    )
    return manifest
