"""A report as one self-contained HTML page that opens offline with no server: every image
inlined as a data URI, the style inline, no script. ``write_index`` writes a report folder's
``index.html`` from what the folder holds; ``write_comparison`` writes the page of several
reports side by side (``analyze compare --page``)."""

from __future__ import annotations

import html
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from string import Template

from voe_lightning import __version__
from voe_lightning.data.store import write_whole
from voe_lightning.report.page.figures import CAPTIONS, figures_html
from voe_lightning.report.page.markdown import markdown_html
from voe_lightning.report.page.markup import figure, table
from voe_lightning.report.page.quadruplets import quadruplets_html
from voe_lightning.report.page.verdicts import (
    causality_html,
    field_metrics_html,
    source_html,
    tests_cell,
    verdict_cell,
    verdict_rows,
    verdict_table,
)
from voe_lightning.report.summary_file import read_summary

#: A report folder's page.
INDEX = "index.html"

STYLE = """
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif; color: #1a1a1a;
       margin: 0 auto; max-width: 1200px; padding: 16px 24px 48px; }
h1 { font-size: 24px; margin: 8px 0; } h2 { font-size: 19px; margin: 28px 0 8px;
     border-bottom: 1px solid #ddd; padding-bottom: 4px; } h3 { font-size: 15px; margin: 16px 0 6px; }
.scroll { overflow-x: auto; } table { border-collapse: collapse; font-size: 12.5px; margin: 6px 0; }
th, td { border: 1px solid #ddd; padding: 3px 7px; text-align: left; vertical-align: top; }
th { background: #f3f3f3; } table.verdicts td { font-size: 13px; }
.tests { min-width: 270px; }
.badge { display: inline-block; padding: 1px 7px; border-radius: 9px; font-weight: 600;
         white-space: nowrap; } .badge.voe { background: #d8f0d8; color: #135e13; }
.badge.no { background: #f6dcdc; color: #8a1c1c; } .badge.none { background: #e8e8e8; color: #555; }
.reason, .note, figcaption { color: #555; font-size: 12px; }
.causality { padding: 6px 10px; border-radius: 4px; background: #eee; }
.causality.passed { background: #e5f4e5; } .causality.failed { background: #f9e0e0; font-weight: 600; }
.videos { display: flex; flex-wrap: wrap; gap: 14px; }
figure { margin: 0 0 12px; } figure.video { width: min-content; }
img.video { display: block; image-rendering: pixelated; } svg.surprise { display: block; }
img.figure { max-width: 100%; height: auto; border: 1px solid #eee; }
.runs { display: grid; gap: 12px; grid-template-columns: repeat(var(--runs), minmax(0, 1fr)); }
details > summary { cursor: pointer; font-weight: 600; margin: 8px 0; }
"""

PAGE = Template(
    """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>$title</title><style>$style</style></head>
<body><h1>$title</h1>
$body
<p class="note">Written by voe_lightning $version. Every image is inlined: this one file opens
offline, with no server.</p>
</body></html>
"""
)


def page(title: str, sections: Mapping[str, str]) -> str:
    """A whole page titled ``title`` (plain text) of ``sections``: heading -> HTML."""
    body = "\n".join(
        f'<section id="{_anchor(heading)}"><h2>{html.escape(heading)}</h2>{content}</section>'
        for heading, content in sections.items()
    )
    return PAGE.substitute(
        title=html.escape(title), style=STYLE, body=body, version=html.escape(__version__)
    )


def _anchor(heading: str) -> str:
    """An id for a section of ``heading``."""
    return "".join(c if c.isalnum() else "-" for c in heading.lower()).strip("-")


def _sections(text: str) -> list[tuple[str, str]]:
    """(title, Markdown) of each ``## `` section of ``text``; what precedes the first, untitled."""
    chunks = re.split(r"^## ", text, flags=re.MULTILINE)
    sections = [("", chunks[0])] if chunks[0].strip() else []
    for chunk in chunks[1:]:
        title, _, body = chunk.partition("\n")
        sections.append((title.strip(), body))
    return sections


def _markdown_file(path: Path, open_sections: int | None = None) -> str:
    """A report's Markdown file as HTML: its first ``open_sections`` sections shown (None:
    all), the rest folded; '' where the file is missing."""
    if not path.is_file():
        return ""
    parts = []
    for index, (title, text) in enumerate(_sections(path.read_text())):
        content = markdown_html(text, heading_level=4)
        heading = html.escape(title)
        if open_sections is None or index < open_sections:
            parts.append((f"<h3>{heading}</h3>" if title else "") + content)
        else:
            parts.append(f"<details><summary>{heading or path.name}</summary>{content}</details>")
    return "".join(parts)


def index_html(report_dir: str | Path) -> str:
    """The page of the report folder ``report_dir`` (its summary.json and what lies beside)."""
    report_dir = Path(report_dir)
    summary = read_summary(report_dir)
    cues = _markdown_file(report_dir / "cues.md", open_sections=1)
    statistics = _markdown_file(report_dir / "summary.md")
    sections = {
        "Verdicts": causality_html(summary) + verdict_table(summary),
        "One quadruplet per concept": quadruplets_html(report_dir),
        "The field's metrics": field_metrics_html(summary),
        "Cue audit": cues or "<p>This report has no cue audit (cues.md).</p>",
        "Figures": figures_html(report_dir),
        "Every statistic": f"<details><summary>summary.md</summary>{statistics}</details>",
    }
    return page("VOE report", {"Source": source_html(summary), **sections})


def write_index(report_dir: str | Path) -> Path:
    """Write ``report_dir/index.html`` (``index_html``), whole, and return its path."""
    path = Path(report_dir) / INDEX
    write_whole({path: index_html(report_dir)})
    return path


def unique_labels(reports: Sequence[tuple[str, Path]]) -> dict[str, Path]:
    """(label, report folder) pairs by label, a repeated label numbered: 'run (2)'."""
    unique: dict[str, Path] = {}
    for label, folder in reports:
        key, number = label, 2
        while key in unique:
            key, number = f"{label} ({number})", number + 1
        unique[key] = Path(folder)
    return unique


def comparison_html(runs: Sequence[tuple[str, Path]]) -> str:
    """The page of several reports ((label, report folder) pairs): their verdicts side by
    side, each one's source and causality line, then each figure of theirs side by side."""
    reports = unique_labels(runs)
    summaries = {label: read_summary(folder) for label, folder in reports.items()}
    concepts = list(dict.fromkeys(v["concept"] for s in summaries.values() for v in s["verdicts"]))
    header = ["concept", *(html.escape(label) for label in summaries)]
    rows = []
    for concept in concepts:
        cells = [f"<strong>{html.escape(concept)}</strong>"]
        for summary in summaries.values():
            verdict = next((v for v in summary["verdicts"] if v["concept"] == concept), None)
            tests = tests_cell(verdict_rows(summary["rows"], concept)) if verdict else ""
            cells.append(verdict_cell(verdict) + (f"<br>{tests}" if tests else ""))
        rows.append(cells)
    sources = "".join(
        f"<h3>{html.escape(label)}</h3>{source_html(summary)}{causality_html(summary)}"
        f'<p class="note">{html.escape(str(reports[label]))}</p>'
        for label, summary in summaries.items()
    )
    sections = {
        "Verdicts side by side": table(header, rows, "verdicts"),
        "The runs": sources,
        "Figures side by side": _figures_side_by_side(reports),
    }
    return page(f"VOE reports compared: {', '.join(reports)}", sections)


def _figures_side_by_side(reports: Mapping[str, Path]) -> str:
    """Each figure name any report has, one column per report."""
    names = [name for name in CAPTIONS if any((f / name).is_file() for f in reports.values())]
    parts = []
    for name in names:
        cells = "".join(
            figure(folder / name, label)
            if (folder / name).is_file()
            else f"<p>{html.escape(label)}: none</p>"
            for label, folder in reports.items()
        )
        parts.append(
            f"<h3>{html.escape(CAPTIONS[name])}</h3>"
            f'<div class="runs" style="--runs: {len(reports)}">{cells}</div>'
        )
    return "".join(parts) or "<p>These reports have no figures.</p>"


def write_comparison(reports: Sequence[tuple[str, Path]], out: str | Path) -> Path:
    """Write ``comparison_html`` of ``reports`` ((label, report folder) pairs) at ``out``,
    whole, and return its path."""
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_whole({path: comparison_html(reports)})
    return path
