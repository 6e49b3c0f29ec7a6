"""Analyses across runs: relative surprise over training read from TensorBoard event files,
separate vs joint runs on one figure (paper Figure 6), the per-concept verdicts of tested runs
side by side, the field's metric set of a windowed model over context length, and how many of a
VRNN-LRU's latents carry information; with the training-set-size
sweep (``voe_lightning.cli.size_sweep``, paper Figure 3) and the calibration of the verdict
(``voe_lightning.audit.calibration``), the subcommands of ``analyze`` (``COMMANDS``).
``python -m voe_lightning analyze
curves|sweep|sweep-plot|compare|context-sweep|latents|null|calibrate``; ``null`` is
``voe_lightning.cli.null``'s.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from matplotlib.figure import Figure

from voe_lightning import specs
from voe_lightning.audit import calibration
from voe_lightning.audit.cues import CUE_TITLES, tracked_cues
from voe_lightning.audit.video_cues import FRAME_LOCAL_CUES
from voe_lightning.cli.null import untrained_null
from voe_lightning.cli.size_sweep import sweep, sweep_plot
from voe_lightning.data.store import collate, open_split, read_manifest
from voe_lightning.model import VRNNLRUModel
from voe_lightning.report.figures import panel_grid, save_figure
from voe_lightning.report.page import write_comparison
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.summary_file import read_summary
from voe_lightning.runs import trained_reports
from voe_lightning.stats.field_metrics import context_sweep, format_field_metrics
from voe_lightning.stats.statistics import POOLED
from voe_lightning.stats.statistics_format import BRIEF, format_alpha, row_text

__all__ = [
    "COMMANDS",
    "RELATIVE_SURPRISE_TAG",
    "comparison_markdown",
    "comparison_rows",
    "latent_usage",
    "read_relative_surprise",
    "read_scalars",
    "relative_surprise_curves_figure",
]

#: TensorBoard tags the training callback logs, one per concept/variant.
RELATIVE_SURPRISE_TAG = re.compile(r"^voe/(?P<concept>[^/]+)/(?P<variant>[^/]+)/relative_surprise$")
#: Line styles of the paper's Figure 6; other run labels cycle through the rest.
PAPER_LINESTYLES = {"joint": "-", "separate": "--"}
#: Line styles and markers of the other runs, in order; each run of a figure gets its own.
_LINESTYLES = (
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
    pattern: re.Pattern | str = RELATIVE_SURPRISE_TAG,
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
        curves[(match["concept"], match["variant"])] = curve
    return curves


def _run_styles(labels: Sequence[str]) -> dict[str, tuple[Any, str, str]]:
    """(line style, marker, its description) per run label: 'joint' solid and 'separate' dashed
    as in the paper, the other labels each a style and a marker no other run of the figure has."""
    paper = {PAPER_LINESTYLES[label] for label in labels if label in PAPER_LINESTYLES}
    free = [style for style in _LINESTYLES if style[0] not in paper]
    names = dict(_LINESTYLES)
    styles, others = {}, 0
    for index, label in enumerate(labels):
        marker, marker_name = _MARKERS[index % len(_MARKERS)]
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
    colors = {}
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


# ----------------------------------------------------------------------------- comparison


def _latest_report(run_dir: str | Path) -> Path:
    """The newest voe_report under ``run_dir``, preferring a training run's own (beside its
    config.yaml) to those `test` writes into sub-folders for external benchmarks, other data,
    concepts, checkpoints or evaluation-only model arguments (``<run>/<what differs>-<hash>/``,
    ``runs.report_folder``); never an untrained copy's (``runs.trained_reports``)."""
    reports = trained_reports(run_dir)
    if not reports:
        raise FileNotFoundError(f"no voe_report/summary.json under {run_dir} (run test first)")
    own = [path for path in reports if (path.parent.parent / "config.yaml").is_file()]
    return (own or reports)[-1].parent


def comparison_rows(runs: Sequence[tuple[str, str | Path]]) -> list[dict[str, Any]]:
    """Per run and concept, the rows its verdict reads (the quadruplet rows of a quadruplet
    concept, the pooled row of another counterbalanced concept, else every variant), each with its verdict, the accuracy range of the
    frame-local cues on the same pairs (from the report's cues.csv, where written) and the
    frame-local cue the model's surprise correlates with most (cue_correlations.csv)."""
    rows = []
    for label, run_dir in runs:
        report = _latest_report(run_dir)
        summary = read_summary(report)
        cue_accuracy: dict[tuple[str, str], list[float]] = {}
        if (report / "cues.csv").is_file():
            with open(report / "cues.csv", newline="") as handle:
                for cue in csv.DictReader(handle):
                    if cue["cue"] in FRAME_LOCAL_CUES and cue["accuracy"] not in ("", "None"):
                        key = (cue["concept"], cue["variant"])
                        cue_accuracy.setdefault(key, []).append(float(cue["accuracy"]))
        tracked = {}
        if (report / "cue_correlations.csv").is_file():
            with open(report / "cue_correlations.csv", newline="") as handle:
                tracked = tracked_cues(
                    {**row, "r": float(row["r"]) if row["r"] not in ("", "None") else None}
                    for row in csv.DictReader(handle)
                )
        by_concept: dict[str, list[dict]] = {}
        for row in summary["rows"]:
            by_concept.setdefault(row["concept"], []).append(row)
        for verdict in summary["verdicts"]:
            concept_rows = by_concept[verdict["concept"]]
            quadruplet = [row for row in concept_rows if row["variant"] in specs.QUADRUPLET_ROWS]
            pooled = [row for row in concept_rows if row["variant"] == POOLED]
            standard = [
                row
                for row in concept_rows
                if row["variant"] not in specs.GENERALIZATION_VARIANT_NAMES
            ]
            for row in quadruplet or pooled or standard:  # generalization variants: never
                accuracies = cue_accuracy.get((row["concept"], row["variant"]), [])
                cue = tracked.get((row["concept"], row["variant"]), {"cue": None, "r": None})
                rows.append(
                    {
                        "run": label,
                        "report": str(report),
                        **row,
                        "voe": verdict["voe"],
                        "verdict": verdict["verdict"],
                        "cue_accuracy_min": min(accuracies, default=None),
                        "cue_accuracy_max": max(accuracies, default=None),
                        "tracked_cue": cue["cue"],
                        "tracked_cue_r": cue["r"],
                    }
                )
    return rows


def comparison_markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """The comparison as a Markdown table, one line per run, concept and verdict row; the
    VOE column's header names the runs' alpha (each run's verdict is at its own)."""
    alphas = {row.get("alpha") for row in rows if row.get("alpha") is not None}
    voe = f"VOE ({format_alpha(alphas.pop())})" if len(alphas) == 1 else "VOE (each run's α)"
    lines = [
        "| run | concept | variant | n | M | t(df) | p | accuracy | frame-local cues: "
        f"accuracy | surprise tracks (r) | {voe} |",
        "|" + "---|" * 11,
    ]
    for row in rows:
        text = row_text(row, BRIEF)
        statistics = f"| {text.mean} | {text.t} | {text.p} | {text.accuracy} "
        cues = (
            "n/a"
            if row["cue_accuracy_min"] is None
            else f"{100 * row['cue_accuracy_min']:.0f}–{100 * row['cue_accuracy_max']:.0f}%"
        )
        tracks = (
            "n/a"
            if row["tracked_cue_r"] is None
            else f"{CUE_TITLES[row['tracked_cue']]} ({row['tracked_cue_r']:+.2f})"
        )
        voe = "n/a" if row["voe"] is None else ("**yes**" if row["voe"] else "no")
        lines.append(
            f"| {row['run']} | {row['concept']} | {row['variant']} | {row['n']} "
            f"{statistics}| {cues} | {tracks} | {voe} |"
        )
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- command line


def _labelled(run: str) -> tuple[str, str]:
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
        relative_surprise_curves_figure([_labelled(run) for run in runs], step_scale), out
    )


def compare(runs: list[str], out: Path | None = None, page: Path | None = None) -> str:
    """Per-concept verdicts of tested runs side by side, as a Markdown table.

    Args:
        runs: tested run directories as [LABEL=]DIR (their latest own voe_report is read).
        out: also write the table here.
        page: also write a self-contained HTML page here (opens offline): the runs' verdicts
            side by side, each one's source and causality check, and their figures side by side.
    """
    labelled = [_labelled(run) for run in runs]
    table = comparison_markdown(comparison_rows(labelled))
    print(table, end="")
    if out:
        Path(out).write_text(table)
    if page:
        reports = [(label, _latest_report(run_dir)) for label, run_dir in labelled]
        print(f"wrote {write_comparison(reports, page)}")
    return table


def context_sweep_table(runs: dict[int, str], out: Path | None = None) -> str:
    """The field's metric set of one windowed model at several context lengths
    (``field_metrics.context_sweep``) per concept/variant, as a Markdown table, from one tested
    run per context length (e.g. ``VJEPA2Scorer`` tested with each ``context_frames``) on the
    same probes.

    Args:
        runs: tested run (or report) directories by context length, e.g. {4: runs/c4,
            8: runs/c8}; the latest voe_report/pairs.csv under each is read.
        out: also write the table here.
    """
    if not runs:
        raise ValueError("give at least one tested run: --runs '{CONTEXT: RUN_DIR, ...}'")
    by_group: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    for context, run in runs.items():
        results = PairResults.from_csv(_latest_report(run) / "pairs.csv")
        for concept, variant, pairs in results.groups(pooled=True):
            by_group.setdefault(f"{concept}/{variant}", {})[int(context)] = (
                pairs.surprise_consistent,
                pairs.surprise_inconsistent,
            )
    missing = sorted(group for group, sides in by_group.items() if len(sides) != len(runs))
    if missing:
        raise ValueError(
            f"{', '.join(missing[:3])} not in every run's report: test every "
            "context length on the same probes"
        )
    rows = {
        f"{group} @ {context}": metrics
        for group, sides in by_group.items()
        for context, metrics in context_sweep(sides).items()
    }
    table = format_field_metrics(rows, "concept/variant @ context length")
    print(table, end="")
    if out:
        Path(out).write_text(table)
    return table


# ----------------------------------------------------------------------------- latent usage


def latent_usage(
    model: VRNNLRUModel, frames: torch.Tensor, threshold: float = 0.01
) -> dict[str, Any]:
    """How much of ``model``'s latent code carries information on uint8 videos ``frames``: batch
    means of KL(posterior || prior) per sequence, of the first frame and per later frame, and the
    latents whose KL per later frame averages above ``threshold`` nats (the rest sit on the
    prior: posterior collapse)."""
    per_latent = model.latent_kl(frames).mean(dim=0)  # [T, latents]
    later = per_latent[1:].mean(dim=0)
    return {
        "kl_per_sequence": per_latent.sum().item(),
        "first_frame": per_latent[0].sum().item(),
        "per_later_frame": per_latent[1:].sum(dim=-1).mean().item(),
        "latents_in_use": int((later > threshold).sum()),
        "latents": later.numel(),
    }


def latents(
    checkpoints: list[str],
    root: Path,
    pairs: int = 16,
    threshold: float = 0.01,
    out: Path | None = None,
) -> str:
    """How many latents of VRNN-LRU checkpoints carry information, as a Markdown table: KL per
    sequence, of the first frame and per later frame, and the latents above ``threshold``, on
    the consistent videos of the first ``pairs`` test pairs of each concept in ``root``.

    Args:
        checkpoints: VRNN-LRU checkpoints as [LABEL=]PATH.
        root: a generated store whose frames have the checkpoints' image size.
        pairs: test pairs read per concept.
        threshold: nats per frame above which a latent counts as in use.
        out: also write the table here.
    """
    if pairs < 1 or threshold < 0:
        raise ValueError(f"pairs must be >= 1 and threshold >= 0, got {pairs} and {threshold}")
    manifest = read_manifest(root)
    if manifest is None:
        raise FileNotFoundError(f"no store at {root} (no manifest.json): generate it first")
    videos = []
    for concept in (c for c in specs.CONCEPTS if c in manifest["concepts"]):
        split = open_split(root, concept, "test")
        videos.append(
            collate([split[i] for i in range(min(pairs, len(split)))])["consistent", "frames"]
        )
    frames = torch.cat(videos)
    lines = [
        "| checkpoint | KL / sequence | first frame | per later frame | latents in use |",
        "|---|---|---|---|---|",
    ]
    for label, path in map(_labelled, checkpoints):
        model = VRNNLRUModel.load_from_checkpoint(path, map_location="cpu", weights_only=True)
        model.eval()
        usage = latent_usage(model, frames, threshold)
        lines.append(
            f"| {label} | {usage['kl_per_sequence']:.1f} | {usage['first_frame']:.1f} | "
            f"{usage['per_later_frame']:.2f} | "
            f"{usage['latents_in_use']} of {usage['latents']} |"
        )
    table = (
        "\n".join(lines) + f"\n\n{len(frames)} consistent test videos of {root}; in use: "
        f"more than {threshold:g} nats per frame after the first.\n"
    )
    print(table, end="")
    if out:
        Path(out).write_text(table)
    return table


#: ``analyze``'s subcommands, as jsonargparse's ``auto_cli`` takes them (``_help``: the summary).
COMMANDS = {
    "_help": "Figures and tables over runs: curves, emergence, sweep, sweep-plot, compare, "
    "context-sweep, latents; untrained initializations of a config: null; and "
    "the verdict's calibration on a store: calibrate.",
    "curves": curves,
    "sweep": sweep,
    "sweep-plot": sweep_plot,
    "compare": compare,
    "context-sweep": context_sweep_table,
    "latents": latents,
    "null": untrained_null,
    "calibrate": calibration.calibrate_store,
}
