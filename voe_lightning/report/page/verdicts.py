"""The page's reading of a report's summary.json: what it was made from (``source_html``), the
causality check (``causality_html``), each concept's verdict with the tests it reads
(``verdict_table``, and its cells, which the comparison of runs reuses) and the field's metrics
(``field_metrics_html``)."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from typing import Any

from voe_lightning import specs
from voe_lightning.report.markdown import format_source
from voe_lightning.report.page.markdown import markdown_html
from voe_lightning.report.page.markup import table
from voe_lightning.stats.causality import Causality
from voe_lightning.stats.field_metrics import format_field_metrics
from voe_lightning.stats.statistics import POOLED
from voe_lightning.stats.statistics_format import BRIEF, format_alpha, row_text


def source_html(summary: Mapping[str, Any]) -> str:
    """What the report was made from, its pairs, alpha and what a video's surprise is."""
    tested = format_source(summary.get("source") or {}).strip()
    facts = (
        f"{summary.get('num_pairs', 'n/a')} probe pairs of {summary.get('num_frames', 'n/a')} "
        f"frames; {format_alpha(summary['alpha'])}; a video's surprise: "
        f"{summary.get('video_surprise', 'n/a')}."
    )
    return "".join(f"<p>{html.escape(text)}</p>" for text in (tested, facts) if text)


def causality_of(summary: Mapping[str, Any]) -> Causality | None:
    """summary.json's causality check as a ``Causality`` (None where it has none)."""
    found = summary.get("causality")
    if not found:
        return None
    return Causality(
        pairs=found["pairs"],
        non_causal=found["non_causal_pairs"],
        largest_difference=found["largest_difference"],
        first_frame=found["first_frame"],
        unchecked=found.get("unchecked_pairs", 0),
    )


def causality_html(summary: Mapping[str, Any]) -> str:
    """The causality line, marked passed or failed."""
    causality = causality_of(summary)
    if causality is None:
        return '<p class="causality">causality: not checked in this report</p>'
    state = "failed" if not causality.causal else "passed" if causality.checked else "unchecked"
    return f'<p class="causality {state}">{html.escape(causality.line())}</p>'


def verdict_rows(rows: Sequence[Mapping[str, Any]], concept: str) -> list[Mapping[str, Any]]:
    """The rows ``concept``'s verdict reads: its quadruplet rows, else its pooled row, else
    its variants (never the generalization variants)."""
    own = [row for row in rows if row["concept"] == concept]
    quadruplet = [row for row in own if row["variant"] in specs.QUADRUPLET_ROWS]
    pooled = [row for row in own if row["variant"] == POOLED]
    variants = [row for row in own if row["variant"] not in specs.GENERALIZATION_VARIANT_NAMES]
    return quadruplet or pooled or variants


def verdict_cell(verdict: Mapping[str, Any] | None) -> str:
    """A verdict as a badge (VOE, no VOE, or neither) and the reason beside it."""
    if verdict is None:
        return '<span class="badge none">n/a</span>'
    text = str(verdict["verdict"])
    kind = "voe" if verdict["voe"] else "none" if verdict["voe"] is None else "no"
    word, _, reason = text.partition(": ")
    badge = f'<span class="badge {kind}">{html.escape(word)}</span>'
    return badge + (f' <span class="reason">{html.escape(reason)}</span>' if reason else "")


def tests_cell(rows: Sequence[Mapping[str, Any]]) -> str:
    """Each row's test, one per line: 'row: t(df) = t, p, M (halves M)'."""
    lines = []
    for row in rows:
        text = row_text(row, BRIEF)
        halves = f" (halves {text.halves})" if text.halves else ""
        star = " *" if text.significant else ""
        lines.append(f"{row['variant']}: {text.t}, {text.p_phrase}{star}; M = {text.mean}{halves}")
    return '<div class="tests">' + "<br>".join(html.escape(line) for line in lines) + "</div>"


def _halves_cell(verdict: Mapping[str, Any]) -> str:
    """Each quadruplet half's own test, and whether both are significant."""
    if not verdict.get("halves"):
        return ""
    both = "both significant" if verdict.get("halves_significant") else "not both significant"
    return f"<strong>{both}</strong>: " + html.escape(str(verdict["halves"]))


def verdict_table(summary: Mapping[str, Any]) -> str:
    """One row per concept: its verdict, the tests it reads, its halves on their own and,
    where the report has them, the verdict of its priors alone (the untrained copy)."""
    priors = summary.get("priors_alone")
    header = ["concept", "verdict", "the tests it reads", "halves on their own"]
    untrained = {}
    if priors:
        header.append(html.escape(str(priors.get("label", "priors alone"))))
        untrained = {v["concept"]: v for v in priors.get("verdicts", [])}
    body = []
    for verdict in summary["verdicts"]:
        concept = verdict["concept"]
        cells = [
            f"<strong>{html.escape(concept)}</strong>",
            verdict_cell(verdict),
            tests_cell(verdict_rows(summary["rows"], concept)),
            _halves_cell(verdict),
        ]
        if priors:
            cells.append(verdict_cell(untrained.get(concept)))
        body.append(cells)
    rules = sorted({str(v["rule"]) for v in summary["verdicts"]})
    note = "Rule: " + "; ".join(rules) + ". * p < alpha, one-tailed." if rules else ""
    return table(header, body, "verdicts") + f'<p class="note">{html.escape(note)}</p>'


def field_metrics_html(summary: Mapping[str, Any]) -> str:
    """The field's metric set per concept/variant (relative and absolute accuracy, AUROC)."""
    metrics = summary.get("field_metrics")
    if not metrics:
        return "<p>This report has no field's metrics.</p>"
    return markdown_html(format_field_metrics(metrics, "concept/variant", max_after_change=True))
