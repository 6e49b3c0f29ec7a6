"""The Markdown a report writes (summary.md, cues.md, the field's metrics) as HTML: headings,
pipe tables, bullet lists and paragraphs, with ``**bold**``, ``*emphasis*`` and ``code``
(``markdown_html``). Only what the report's own writers produce, nothing more."""

from __future__ import annotations

import html
import re
from collections.abc import Iterator

from voe_lightning.report.page.markup import table

_BOLD = re.compile(r"\*\*(.+?)\*\*")
_EMPHASIS = re.compile(r"(?<![\w*])\*(?!\s)(.+?)(?<!\s)\*(?![\w*])")
_CODE = re.compile(r"`([^`]+)`")


def inline(text: str) -> str:
    """One line of Markdown text as escaped HTML with its bold, emphasis and code."""
    escaped = html.escape(text, quote=False)
    escaped = _CODE.sub(r"<code>\1</code>", escaped)
    escaped = _BOLD.sub(r"<strong>\1</strong>", escaped)
    return _EMPHASIS.sub(r"<em>\1</em>", escaped)


def _cells(line: str) -> list[str]:
    """A pipe-table line's cells, as inline HTML."""
    return [inline(cell.strip()) for cell in line.strip().strip("|").split("|")]


def _blocks(text: str) -> Iterator[tuple[str, list[str]]]:
    """(kind, lines) of each block: heading, table, list or paragraph."""
    kind, lines = "", list[str]()
    for line in text.splitlines():
        new = (
            "heading"
            if line.startswith("#")
            else "table"
            if line.startswith("|")
            else "list"
            if line.startswith("- ")
            else "paragraph"
            if line.strip()
            else ""
        )
        if new != kind or new == "heading":
            if lines:
                yield kind, lines
            kind, lines = new, []
        if new:
            lines.append(line)
    if lines:
        yield kind, lines


def markdown_html(text: str, heading_level: int = 3) -> str:
    """``text`` as HTML; its headings of any level become ``<h{heading_level}>``."""
    parts = []
    for kind, lines in _blocks(text):
        if kind == "heading":
            tag = f"h{heading_level}"
            parts.append(f"<{tag}>{inline(lines[0].lstrip('#').strip())}</{tag}>")
        elif kind == "table":
            rows = [_cells(line) for line in lines if not re.fullmatch(r"\|?[\s:|-]+\|?", line)]
            parts.append(table(rows[0], rows[1:]))
        elif kind == "list":
            parts.append(
                "<ul>" + "".join(f"<li>{inline(line[2:])}</li>" for line in lines) + "</ul>"
            )
        else:
            parts.append("<p>" + "<br>".join(inline(line) for line in lines) + "</p>")
    return "\n".join(parts)
