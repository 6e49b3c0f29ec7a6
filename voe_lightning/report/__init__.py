"""The paper's Results section for one run (paper §5, Figures 4-5, Appendices B-C), written to
``<run dir>/voe_report/`` by ``write_report`` or, during ``test``, by
``voe_lightning.callbacks.VOEReportCallback``, from one ``ReportInputs``: the per-pair results
in ``pairs``, the statistics rows in ``tables``, summary.md's text in ``markdown`` (and
``priors_alone``'s section), the summary files in ``summary`` (read back by ``summary_file``),
the figures in ``figures``, and the page a person opens in ``page``.

Files: ``summary.json``/``summary.csv``/``summary.md`` (one row per concept/variant, a
``pooled`` row per concept with a counterbalanced pair, and each concept's VOE verdict; with
a surprise window, its rows beside them and in ``summary_window.csv``), ``pairs.csv`` (one row
per probe pair, with per-frame surprise and its first difference, so anyone can redo the
statistics), ``cues.md``/``cues.csv``/``cues.json`` (the cue audit on the same pairs, beside the
model's rows, then how the model's relative surprise correlates with each cue's difference;
see ``voe_lightning.audit.cues``), ``cue_correlations.csv`` and ``cue_scatter.png`` (those
correlations in full and drawn), ``histograms.png``, ``surprise_per_frame.png``,
``predictions_<concept>.png``, ``tsne_object_persistence.png``, and ``index.html`` (one
self-contained page of it all, with one quadruplet per concept playing, from the frames saved
in ``examples/``).

A report is written whole into a new folder that then replaces ``voe_report/``, so an
interrupted ``test`` leaves the previous report intact and no file of an earlier report (say,
another concept's predictions) survives beside a new summary. The temporary folders carry the
host and process id, so the next report removes those a killed process (SIGKILL) left.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from voe_lightning.audit import cue_report, cues
from voe_lightning.data.store import current_umask, remove_stale, temporary_prefix
from voe_lightning.report.figures import PredictionExample, write_figures
from voe_lightning.report.markdown import VRNN_SURPRISE
from voe_lightning.report.page import write_page
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.summary import write_summary
from voe_lightning.report.tables import summarize
from voe_lightning.stats.surprise_window import SurpriseWindow


@dataclass(frozen=True)
class ReportInputs:
    """Everything one report is made of: the per-pair ``results`` tested at ``alpha`` (the
    run's), ``bootstrap`` resamples seeded by ``seed``; ``predictions`` give
    predictions_<concept>.png, ``trajectories`` (see ``tsne_figure``, labelled by
    ``trajectory_labels``) tsne_object_persistence.png, ``cue_audit`` (scores of the same
    pairs) cues.md/csv/json, cue_correlations.csv and cue_scatter.png; ``surprise`` names what a
    frame's surprise is (the model's ``SURPRISE``), ``source`` (checkpoint, its global step,
    data root, concepts) goes into summary.json; a ``window`` other than all frames adds its
    tables beside the paper's, and ``priors_alone`` (an untrained copy's summary) its rows
    labelled "priors alone (untrained)" (``write_summary``)."""

    results: PairResults
    alpha: float
    bootstrap: int = 2000
    seed: int = 0
    predictions: Sequence[PredictionExample] | None = None
    trajectories: Mapping[str, Any] | None = None
    trajectory_labels: Sequence[str] | None = None
    cue_audit: cues.CueAudit | None = None
    surprise: str = VRNN_SURPRISE
    source: Mapping[str, Any] | None = None
    window: SurpriseWindow = SurpriseWindow()
    priors_alone: Mapping[str, Any] | None = None


def write_report(
    inputs: ReportInputs, out_dir: str | Path, echo: bool = True
) -> list[dict[str, Any]]:
    """Write ``out_dir/voe_report/`` (module docstring) from ``inputs`` and return the summary
    rows; ``echo`` prints the Markdown tables."""
    if len(inputs.results) == 0:
        raise ValueError("no probe results to report")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in (STAGING, REPLACED):
        remove_stale(out_dir, name)
    staging = Path(tempfile.mkdtemp(prefix=temporary_prefix(STAGING), dir=out_dir))
    try:
        rows = _write_files(inputs, staging, echo)
        write_page(staging)
        report_dir = _replace_folder(staging, out_dir / "voe_report")
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    if echo:
        print(f"VOE report written to {report_dir}")
    return rows


#: Names of the temporary folders beside voe_report/: the new report, and the old one on its way out.
STAGING, REPLACED = "voe_report", "voe_report.replaced"


def _replace_folder(new: Path, target: Path) -> Path:
    """Put the folder ``new`` in place of ``target`` (removing the old one whole), with the
    mode a folder ``mkdir`` makes would have (``mkdtemp``'s 0700 hides it from a lab)."""
    os.chmod(new, 0o777 & ~current_umask())
    if target.exists():
        replaced = Path(tempfile.mkdtemp(prefix=temporary_prefix(REPLACED), dir=target.parent))
        os.replace(target, replaced / target.name)
        os.replace(new, target)
        shutil.rmtree(replaced, ignore_errors=True)
    else:
        os.replace(new, target)
    return target


def _write_files(inputs: ReportInputs, report_dir: Path, echo: bool) -> list[dict[str, Any]]:
    """Every file of the report (``write_report``) into ``report_dir``; the summary rows."""
    results, alpha, cue_audit = inputs.results, inputs.alpha, inputs.cue_audit
    rows = summarize(results, alpha=alpha, bootstrap=inputs.bootstrap, seed=inputs.seed)
    window_rows = (
        None
        if inputs.window.all_frames
        else summarize(
            results.windowed(inputs.window),
            alpha=alpha,
            bootstrap=inputs.bootstrap,
            seed=inputs.seed,
        )
    )
    cue_rows = [] if cue_audit is None else cue_audit.rows(alpha=alpha)
    followers = cue_report.follower_names(cue_rows)
    markdown = write_summary(
        results,
        rows,
        report_dir,
        alpha=alpha,
        bootstrap=inputs.bootstrap,
        surprise=inputs.surprise,
        source=inputs.source,
        window=inputs.window,
        window_rows=window_rows,
        priors_alone=inputs.priors_alone,
        followers_passing=cue_report.followers_passing(cue_rows) if followers else None,
    )
    correlations = None
    if cue_audit is not None:
        cue_markdown, correlations = _write_cue_audit(inputs, cue_audit, rows, cue_rows, report_dir)
        markdown += cue_markdown
    write_figures(
        results,
        rows,
        report_dir,
        inputs.predictions,
        inputs.trajectories,
        inputs.trajectory_labels,
        seed=inputs.seed,
        cue_audit=cue_audit,
        correlation_rows=correlations,
    )
    if echo:
        _print_markdown(markdown)
    return rows


def _write_cue_audit(
    inputs: ReportInputs,
    cue_audit: cues.CueAudit,
    rows: list[dict[str, Any]],
    cue_rows: list[dict[str, Any]],
    report_dir: Path,
) -> tuple[str, list[dict[str, Any]]]:
    """The cue audit's files of the model's own pairs (refused unless they are the same pairs
    in the same order; ``cue_rows`` its rows); its Markdown and the model's correlations with
    each cue."""
    results, alpha = inputs.results, inputs.alpha
    if len(cue_audit) != len(results):
        raise ValueError(
            f"the cue audit scored {len(cue_audit)} pairs, the model "
            f"{len(results)}: they must be the same pairs"
        )
    if tuple(cue_audit.concepts) != results.concept or tuple(cue_audit.variants) != results.variant:
        raise ValueError("the cue audit's pairs are not the model's pairs in the same order")
    correlations = cue_audit.model_correlations(results.relative_surprise, alpha=alpha)
    title = "Cue audit on the model's test pairs"
    cue_report.write_audit(
        cue_rows,
        report_dir,
        model_rows=rows,
        title=title,
        correlation_rows=correlations,
        alpha=alpha,
        num_pairs=len(cue_audit),
    )
    markdown = (
        "\n"
        + cue_report.format_markdown(cue_rows, rows, title)
        + "\n"
        + cue_report.format_correlations(correlations)
    )
    if cue_report.follower_names(cue_rows):
        markdown += "\n" + cue_report.format_followers(cue_rows, rows)
    return markdown, correlations


def _print_markdown(markdown: str) -> None:
    from rich.console import Console
    from rich.markdown import Markdown

    console = Console()
    if console.is_terminal:
        console.print(Markdown(markdown))
    else:
        print(markdown, end="")
