"""Contact sheets like the paper's Figure 1: each probe pair as a consistent row above an
inconsistent row with the manipulation frame outlined, and each training clip as a labelled
row, frames left to right. From freshly rendered records or from a store."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only; no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
from tensordict import TensorDictBase  # noqa: E402

from voe_lightning import specs  # noqa: E402

GAP = 2  # pixels between frames
MARK_COLOR = "#e8112d"


@dataclass
class Row:
    """One strip of frames: a label, uint8 frames [T, H, W, 3], the frame to outline (or None)
    and the section title it starts (or None)."""

    label: str
    frames: np.ndarray
    marked_frame: int | None = None
    section: str | None = None


def record_rows(record: TensorDictBase) -> list[Row]:
    """The rows of one record: two for a probe pair (consistent above inconsistent), one for a clip."""
    concept = specs.concept_name(record)
    if "consistent" in record.keys():
        variant = specs.variant_name(record)
        mark = int(record["manipulation_frame"])
        title = (
            f"{concept} probe, {variant} (seed {int(record['seed'])}); outlined: manipulation frame"
        )
        return [
            Row("consistent", record["consistent", "frames"].numpy(), mark, title),
            Row("inconsistent", record["inconsistent", "frames"].numpy(), mark),
        ]
    kind = specs.CLIP_KINDS[int(record["kind"])]
    label = "example" if kind == "example" else f"control:\n{kind.replace('_', ' ')}"
    return [Row(label, record["frames"].numpy(), None, None)]


def _strip(frames: np.ndarray) -> np.ndarray:
    num_frames, height, width, _ = frames.shape
    strip = np.full((height, num_frames * (width + GAP) - GAP, 3), 255, np.uint8)
    for t in range(num_frames):
        strip[:, t * (width + GAP) : t * (width + GAP) + width] = frames[t]
    return strip


def draw_rows(
    rows: Sequence[Row], path: str | os.PathLike[str], title: str | None = None, scale: float = 1.5
) -> Path:
    """Draw ``rows`` (all of one video size) into a PNG at ``path``; returns the path."""
    if not rows:
        raise ValueError("a contact sheet needs at least one row")
    num_frames, height, width, _ = rows[0].frames.shape
    dpi = 100
    strip_width = num_frames * (width + GAP) - GAP
    longest = max(len(line) for row in rows for line in row.label.splitlines())
    label_width, section_height = 24 + 7 * longest, 22  # ~7 px a character at 9 pt
    row_height = height * scale + 6
    sections = sum(row.section is not None for row in rows)
    fig_height = len(rows) * row_height + sections * section_height + (34 if title else 8)
    fig_width = label_width + strip_width * scale + 12
    figure = plt.figure(figsize=(fig_width / dpi, fig_height / dpi), dpi=dpi)
    top = fig_height - (34 if title else 8)
    if title:
        figure.text(
            0.5, 1 - 14 / fig_height, title, ha="center", va="center", fontsize=11, weight="bold"
        )
    for row in rows:
        if row.frames.shape != (num_frames, height, width, 3):
            raise ValueError(
                f"row {row.label!r} has frames {row.frames.shape}, expected {(num_frames, height, width, 3)}"
            )
        if row.section is not None:
            top -= section_height
            figure.text(
                label_width / fig_width,
                (top + 6) / fig_height,
                row.section,
                fontsize=9,
                va="bottom",
            )
        top -= row_height
        axes = figure.add_axes(
            (
                label_width / fig_width,
                (top + 3) / fig_height,
                strip_width * scale / fig_width,
                height * scale / fig_height,
            )
        )
        axes.imshow(_strip(row.frames), interpolation="nearest")
        axes.set_xticks([t * (width + GAP) + width / 2 for t in range(num_frames)])
        axes.set_xticklabels([])
        axes.set_yticks([])
        axes.tick_params(length=0)
        for spine in axes.spines.values():
            spine.set_visible(False)
        axes.text(-8, height / 2, row.label, ha="right", va="center", fontsize=9)
        if row.marked_frame is not None:
            left = row.marked_frame * (width + GAP) - 1
            axes.add_patch(
                Rectangle(
                    (left, -0.5), width + 1, height, fill=False, edgecolor=MARK_COLOR, linewidth=2
                )
            )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=dpi)
    plt.close(figure)
    return path


def write_records_sheet(
    records: Sequence[TensorDictBase], path: str | os.PathLike[str], title: str | None = None
) -> Path:
    """A contact sheet of probe pairs and/or clips, in the order given."""
    return draw_rows([row for record in records for row in record_rows(record)], path, title)


def write_concept_sheet(
    concept: str,
    path: str | os.PathLike[str],
    seed: int = 0,
    include_generalization: bool = False,
    **video_options: Any,
) -> Path:
    """Render one probe pair per probe variant and one clip per training kind of ``concept``
    (seed ``seed``) and draw them as a contact sheet at ``path``."""
    from voe_lightning.scenes import generate_clip, generate_probe

    specs.check_concept(concept)
    variants = specs.STANDARD_VARIANTS[concept]
    if include_generalization:
        variants += specs.GENERALIZATION_VARIANTS[concept]
    records = [generate_probe(concept, variant, seed, **video_options) for variant in variants]
    records += [
        generate_clip(concept, kind, seed, **video_options)
        for kind in specs.CLIP_KINDS_BY_CONCEPT[concept]
    ]
    return write_records_sheet(records, path, title=concept.replace("_", " "))


def write_store_sheet(
    root: str | os.PathLike[str],
    concept: str,
    path: str | os.PathLike[str],
    probe_split: str = "test",
    scan: int = 256,
) -> Path:
    """A contact sheet of ``concept`` from the store at ``root``: the first pair of each probe
    variant in ``probe_split`` and the first clip of each kind in train (looking at most
    ``scan`` records into each split; splits are interleaved, so the first few suffice)."""
    from voe_lightning.data.store.read import open_split

    records = []
    for split, field, names in (
        (probe_split, "variant", specs.VARIANTS),
        ("train", "kind", specs.CLIP_KINDS),
    ):
        dataset, seen = open_split(root, concept, split), set()
        for index in range(min(len(dataset), scan)):
            record = dataset[index]
            name = names[int(record[field])]
            if name not in seen:
                seen.add(name)
                records.append(record)
    if not records:
        raise ValueError(
            f"the store at {root} holds no {concept} records in {probe_split} or train"
        )
    return write_records_sheet(records, path, title=concept.replace("_", " "))
