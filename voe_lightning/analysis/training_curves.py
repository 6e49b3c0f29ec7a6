"""Relative surprise over training, read from a run's TensorBoard event files and drawn per
concept and run (paper Figure 6): ``python -m voe_lightning analyze curves``."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from voe_lightning.report.figures import panel_grid, save_figure

#: TensorBoard tags the training callback logs, one per concept/variant.
RELATIVE_SURPRISE_TAG = re.compile(r"^voe/(?P<concept>[^/]+)/(?P<variant>[^/]+)/relative_surprise$")
#: Line styles of the paper's Figure 6; other run labels cycle through the rest.
PAPER_LINESTYLES = {"joint": "-", "separate": "--"}
#: A matplotlib line style: a name, or (offset, on-off dash sequence).
LineStyle = str | tuple[int, tuple[int, ...]]
#: Line styles and markers of the other runs, in order; each run of a figure gets its own.
_LINESTYLES: tuple[tuple[LineStyle, str], ...] = (
    ("-", "solid"),
    ("--", "dashed"),
    (":", "dotted"),
    ("-.", "dash-dot"),
    ((0, (5, 1, 1, 1, 1, 1)), "dash-dot-dot"),
    ((0, (8, 3)), "long-dashed"),
)
_MARKERS = (
    ("o", "circles"),
    ("s", "squares"),
    ("^", "triangles"),
    ("D", "diamonds"),
    ("v", "down-triangles"),
    ("P", "pluses"),
    ("X", "crosses"),
    ("*", "stars"),
)


def _is_evaluation(accumulator: Any) -> bool:
    """Whether an event file is a ``validate``/``test`` evaluation's, not training's: no
    training scalar (``train/...``) and every scalar at step 0, where ``validate`` logs (a
    fit validates after a step at least); its values are a trained model's, no curve's start."""
    tags = accumulator.Tags()["scalars"]
    return not any(tag.startswith("train/") for tag in tags) and all(
        event.step == 0 for tag in tags for event in accumulator.Scalars(tag)
    )


def read_scalars(
    run_dir: str | Path,
    pattern: re.Pattern[str] | str = RELATIVE_SURPRISE_TAG,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Scalars whose tag matches ``pattern`` from every training event file under ``run_dir``
    (not a later ``validate``'s, ``_is_evaluation``, in the run or a folder of other data), as
    tag -> (steps, values) sorted by step (a later event wins on a repeated step, as when a
    run is resumed)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run_dir = Path(run_dir)
    if not run_dir.exists():
        raise FileNotFoundError(f"run directory {run_dir} does not exist")
    files = sorted(run_dir.rglob("events.out.tfevents.*"))
    if not files:
        raise FileNotFoundError(
            f"no TensorBoard event files (events.out.tfevents.*) under {run_dir}"
        )
    pattern = re.compile(pattern) if isinstance(pattern, str) else pattern
    collected: dict[str, dict[int, tuple[float, float]]] = {}
    for file in files:
        accumulator = EventAccumulator(str(file), size_guidance={"scalars": 0})
        accumulator.Reload()
        if _is_evaluation(accumulator):
            continue
        for tag in accumulator.Tags()["scalars"]:
            if pattern.match(tag):
                by_step = collected.setdefault(tag, {})
                for event in accumulator.Scalars(tag):
                    if event.step not in by_step or event.wall_time >= by_step[event.step][0]:
                        by_step[event.step] = (event.wall_time, event.value)
    return {
        tag: (np.array(sorted(by_step)), np.array([by_step[s][1] for s in sorted(by_step)]))
        for tag, by_step in sorted(collected.items())
    }


def read_relative_surprise(
    run_dir: str | Path,
) -> dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]:
    """(concept, variant) -> (steps, relative surprise) of one run."""
    curves = {}
    for tag, curve in read_scalars(run_dir).items():
        match = RELATIVE_SURPRISE_TAG.match(tag)
        assert match is not None  # read_scalars keeps the tags the pattern matches
        curves[(match["concept"], match["variant"])] = curve
    return curves


def _run_styles(labels: Sequence[str]) -> dict[str, tuple[LineStyle, str, str]]:
    """(line style, marker, its description) per run label: 'joint' solid and 'separate' dashed
    as in the paper, the other labels each a style and a marker no other run of the figure has."""
    paper = {PAPER_LINESTYLES[label] for label in labels if label in PAPER_LINESTYLES}
    free = [style for style in _LINESTYLES if style[0] not in paper]
    names = dict(_LINESTYLES)
    styles, others = {}, 0
    for index, label in enumerate(labels):
        marker, marker_name = _MARKERS[index % len(_MARKERS)]
        line: LineStyle
        if label in PAPER_LINESTYLES:
            line, line_name = PAPER_LINESTYLES[label], names[PAPER_LINESTYLES[label]]
        else:
            line, line_name = free[others % len(free)]
            others += 1
        styles[label] = (line, marker, f"{line_name}, {marker_name}")
    return styles


def relative_surprise_curves_figure(
    runs: Sequence[tuple[str, str | Path]],
    step_scale: Mapping[str, float] | None = None,
) -> Figure:
    """Relative surprise over training per concept (paper Figure 6): one panel per concept,
    a colour per variant, a line style per run label ('joint' solid, 'separate' dashed).
    ``runs`` is a list of (label, run directory); several directories may share a label (the
    separately trained models, one per concept), never a concept/variant's curve. ``step_scale`` multiplies a label's steps,
    e.g. to compare joint and separate runs at equal examples per concept."""
    if not runs:
        raise ValueError("no runs given: pass at least one (label, run directory)")
    step_scale = dict(step_scale or {})
    unknown = set(step_scale) - {label for label, _ in runs}
    if unknown:
        raise ValueError(f"step_scale names unknown run labels {sorted(unknown)}")
    curves: dict[str, dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]] = {}
    sources: dict[tuple[str, str, str], str | Path] = {}
    for label, run_dir in runs:
        found = read_relative_surprise(run_dir)
        if not found:
            raise ValueError(
                f"{run_dir} has no voe/<concept>/<variant>/relative_surprise scalars "
                "(was the VOE probe callback enabled during fit?)"
            )
        for concept, variant in found:  # runs share a label only for different concepts
            first = sources.setdefault((label, concept, variant), run_dir)
            if first != run_dir:
                raise ValueError(
                    f"runs {first} and {run_dir} are both labelled {label!r} and both have "
                    f"{concept}/{variant} curves, so one would hide the other: give each its "
                    "own label (LABEL=DIR); runs share a label only for different concepts"
                )
        curves.setdefault(label, {}).update(found)
    labels = list(curves)
    styles = _run_styles(labels)
    concepts = list(dict.fromkeys(c for label in labels for c, _ in curves[label]))
    figure, axes = panel_grid(len(concepts), 5.0, 3.6, max_cols=3)
    colors: dict[tuple[str, str], str] = {}
    for ax, concept in zip(axes, concepts):
        variants = list(
            dict.fromkeys(v for label in labels for c, v in curves[label] if c == concept)
        )
        for variant_index, variant in enumerate(variants):
            color = colors.setdefault((concept, variant), f"C{variant_index}")
            for label in labels:
                if (concept, variant) in curves[label]:
                    steps, values = curves[label][(concept, variant)]
                    ax.plot(
                        steps * step_scale.get(label, 1.0),
                        values,
                        color=color,
                        linestyle=styles[label][0],
                        marker=styles[label][1],
                        markersize=3,
                        label=f"{variant} ({label})",
                    )
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.set_title(concept, fontsize=10)
        ax.set_xlabel("training step" + (" (scaled)" if step_scale else ""))
        ax.set_ylabel("relative surprise")
        ax.legend(fontsize=7)
    legend = "; ".join(f"{label}: {styles[label][2]}" for label in labels)
    figure.suptitle(f"Relative surprise over training ({legend})", fontsize=10)
    return figure


def labelled_run(run: str) -> tuple[str, str]:
    """``LABEL=DIR`` as (LABEL, DIR); a bare DIR is labelled by its name."""
    label, equals, directory = run.partition("=")
    return (label, directory) if equals else (Path(run).name, run)


def curves(runs: list[str], out: Path, step_scale: dict[str, float] | None = None) -> Path:
    """Relative surprise over training per concept and run (paper Figure 6), as a PNG.

    Args:
        runs: run directories as [LABEL=]DIR; label joint runs 'joint' (solid) and separate
            runs 'separate' (dashed); a label may repeat for runs of different concepts.
        out: PNG to write.
        step_scale: a factor per label multiplying its steps, e.g. {joint: 0.2} for examples
            per concept.
    """
    return save_figure(
        relative_surprise_curves_figure([labelled_run(run) for run in runs], step_scale), out
    )
