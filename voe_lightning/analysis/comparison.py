"""Tested runs side by side: the per-concept verdicts of their reports and their mean ± sd
over the runs (``analyze compare``), and the field's metric set of a windowed model over
context length (``analyze context-sweep``)."""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from voe_lightning import specs
from voe_lightning.analysis.training_curves import labelled_run
from voe_lightning.audit.cues import CUE_TITLES, tracked_cues
from voe_lightning.audit.video_cues import FRAME_LOCAL_CUES
from voe_lightning.report.page import write_comparison
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.summary_file import read_summary
from voe_lightning.runs import trained_reports
from voe_lightning.stats.field_metrics import context_sweep, format_field_metrics
from voe_lightning.stats.statistics import POOLED
from voe_lightning.stats.statistics_format import BRIEF, format_alpha, row_text


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
        tracked: dict[tuple[str, str], Mapping[str, Any]] = {}
        if (report / "cue_correlations.csv").is_file():
            with open(report / "cue_correlations.csv", newline="") as handle:
                tracked = tracked_cues(
                    {**row, "r": float(row["r"]) if row["r"] not in ("", "None") else None}
                    for row in csv.DictReader(handle)
                )
        by_concept: dict[str, list[dict[str, Any]]] = {}
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
                best = tracked.get((row["concept"], row["variant"]), {"cue": None, "r": None})
                rows.append(
                    {
                        "run": label,
                        "report": str(report),
                        **row,
                        "voe": verdict["voe"],
                        "verdict": verdict["verdict"],
                        "cue_accuracy_min": min(accuracies, default=None),
                        "cue_accuracy_max": max(accuracies, default=None),
                        "tracked_cue": best["cue"],
                        "tracked_cue_r": best["r"],
                    }
                )
    return rows


def comparison_markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """The comparison as a Markdown table, one line per run, concept and verdict row; the
    VOE column's header names the runs' alpha (each run's verdict is at its own)."""
    alphas: set[float] = {row["alpha"] for row in rows if row.get("alpha") is not None}
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


def over_runs_markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """Per concept and verdict row, t's mean ± sd over the runs (seeds of one config, say:
    the spread the field asks a result to report), the halves' M as mean ± sd, and how many
    runs show VOE; empty for fewer than two runs."""
    runs = list(dict.fromkeys(str(row["run"]) for row in rows))
    if len(runs) < 2:
        return ""
    groups: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["concept"], row["variant"]), []).append(row)
    lines = [
        f"Over the {len(runs)} runs (mean ± sd; sd with n − 1):",
        "",
        "| concept | variant | runs | t | halves M | VOE |",
        "|---|---|---|---|---|---|",
    ]
    for (concept, variant), group in groups.items():
        t = _mean_sd([row["t"] for row in group])
        halves = " / ".join(
            _mean_sd([row.get(half) for row in group]) for half in ("first_half", "second_half")
        )
        shown = sum(bool(row["voe"]) for row in group if row["voe"] is not None)
        lines.append(
            f"| {concept} | {variant} | {len(group)} | {t} | {halves} | {shown} of {len(group)} |"
        )
    return "\n".join(lines) + "\n"


def _mean_sd(values: Sequence[float | None]) -> str:
    """``mean ± sd`` of the values given (n/a where none is)."""
    known = np.array([value for value in values if value is not None], dtype=float)
    known = known[np.isfinite(known)]
    if known.size == 0:
        return "n/a"
    sd = f" ± {known.std(ddof=1):.2f}" if known.size > 1 else ""
    return f"{known.mean():.2f}{sd}"


def compare(runs: list[str], out: Path | None = None, page: Path | None = None) -> str:
    """Per-concept verdicts of tested runs side by side, as a Markdown table.

    Args:
        runs: tested run directories as [LABEL=]DIR (their latest own voe_report is read).
        out: also write the table here.
        page: also write a self-contained HTML page here (opens offline): the runs' verdicts
            side by side, each one's source and causality check, and their figures side by side.
    """
    labelled = [labelled_run(run) for run in runs]
    rows = comparison_rows(labelled)
    table = comparison_markdown(rows)
    spread = over_runs_markdown(rows)
    table += f"\n{spread}" if spread else ""
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
