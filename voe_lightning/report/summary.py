"""The report's summary files: pairs.csv, summary.json, summary.csv and summary.md (and, with
a surprise window, summary_window.csv), written by ``write_summary`` from ``summarize``'s rows."""

from __future__ import annotations

import csv
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from voe_lightning.audit.cue_report import passing_sentence
from voe_lightning.report.markdown import format_markdown, format_source
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.priors_alone import format_priors_alone, priors_alone_document
from voe_lightning.report.summary_file import file_sha256
from voe_lightning.report.tables import SUMMARY_COLUMNS, field_metric_rows
from voe_lightning.stats.field_metrics import format_field_metrics
from voe_lightning.stats.statistics_format import json_row
from voe_lightning.stats.surprise_window import SurpriseWindow
from voe_lightning.stats.verdicts import Verdict, concept_verdicts


def write_summary(
    results: PairResults,
    rows: Sequence[Mapping[str, Any]],
    report_dir: Path,
    *,
    alpha: float,
    bootstrap: int,
    surprise: str,
    source: Mapping[str, Any] | None = None,
    window: SurpriseWindow = SurpriseWindow(),
    window_rows: Sequence[Mapping[str, Any]] | None = None,
    priors_alone: Mapping[str, Any] | None = None,
    followers_passing: Mapping[str, Sequence[str]] | None = None,
) -> str:
    """Write pairs.csv, summary.json (with ``source``: what the report was made from, and
    pairs.csv's SHA-256, which ``PairResults.from_csv`` checks), summary.csv and summary.md
    (of ``summarize``'s ``rows``, over all frames, and the field's metrics of
    ``field_metric_rows``) into ``report_dir``; with a ``window``
    other than all frames, its ``window_rows`` go beside them: summary.json's ``window``,
    summary_window.csv and a section of summary.md; ``priors_alone`` (the untrained copy's
    summary, ``null.priors_alone``) gives summary.json's ``priors_alone`` and its section of
    summary.md; ``followers_passing`` (``cue_report.followers_passing`` of the followers of
    the model's inputs) gives summary.json's ``followers_passing`` and a line under the
    verdicts: a VOE a follower also gets is no evidence of physics. Return the Markdown
    summary."""
    results.to_csv(report_dir / "pairs.csv")
    causality = results.causality
    verdicts = concept_verdicts(rows, alpha, causality)
    document = {
        "source": dict(source or {}),
        "alpha": alpha,
        "bootstrap_resamples": bootstrap,
        "num_pairs": len(results),
        "pairs_csv_sha256": file_sha256(report_dir / "pairs.csv"),
        "num_frames": results.num_frames,
        "video_surprise": f"sum over frames of {surprise}",
        "surprise_window": window.as_config(),
        "causality": causality.as_dict(),
        **_tables(rows, verdicts),
        "field_metrics": field_metric_rows(results),
    }
    with open(report_dir / "summary.csv", "w", newline="") as handle:
        _write_rows(handle, rows)
    markdown = format_source(document["source"]) + format_markdown(
        rows, verdicts, surprise, causality=causality
    )
    if followers_passing is not None:
        document["followers_passing"] = {c: list(f) for c, f in followers_passing.items()}
        markdown += (
            "\nFollowers of the model's own inputs (cues.md): "
            + passing_sentence(followers_passing)
            + "\n"
        )
    if priors_alone is not None:
        document["priors_alone"] = priors_alone_document(priors_alone)
        markdown += "\n" + format_priors_alone(
            document["rows"], document["verdicts"], document["priors_alone"]
        )
    if not window.all_frames:
        assert window_rows is not None, "a surprise window needs its rows"
        window_verdicts = concept_verdicts(window_rows, alpha, causality)
        document["window"] = {
            "surprise_window": window.as_config(),
            "video_surprise": f"sum over the {window.describe()} of {surprise}",
            **_tables(window_rows, window_verdicts),
        }
        with open(report_dir / "summary_window.csv", "w", newline="") as handle:
            _write_rows(handle, window_rows)
        markdown += (
            f"\n## Surprise window: {window.describe()}\n\nBeside the paper's sums "
            "over all frames above, never instead of them.\n\n"
            + format_markdown(window_rows, window_verdicts, surprise, window, causality)
        )
    else:
        markdown += "\nSurprise window: all frames (the paper's).\n"
    markdown += "\n## The field's metrics\n\n" + format_field_metrics(
        document["field_metrics"], "concept/variant", max_after_change=True
    )
    (report_dir / "summary.json").write_text(json.dumps(document, indent=2) + "\n")
    (report_dir / "summary.md").write_text(markdown)
    return markdown


def _tables(rows: Sequence[Mapping[str, Any]], verdicts: Sequence[Verdict]) -> dict[str, Any]:
    """summary.json's ``rows`` (strict JSON) and ``verdicts`` (of those rows, withheld where
    the causality check failed)."""
    return {
        "rows": [json_row(row) for row in rows],
        "verdicts": [
            {
                "concept": v.concept,
                "voe": v.voe,
                "verdict": v.text(),
                "rule": v.rule,
                "halves_significant": v.halves_significant,
                "halves": v.halves,
            }
            for v in verdicts
        ],
    }


def _write_rows(handle: Any, rows: Sequence[Mapping[str, Any]]) -> None:
    """``summarize``'s rows as CSV (``SUMMARY_COLUMNS``)."""
    writer = csv.DictWriter(handle, fieldnames=SUMMARY_COLUMNS)
    writer.writeheader()
    writer.writerows(rows)
