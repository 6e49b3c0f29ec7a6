"""The HTML pieces every section of a page is made of: inline data URIs (``data_uri``),
tables of already-escaped cells (``table``) and figures (``figure``)."""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from pathlib import Path

#: MIME types of the files a page inlines, by suffix.
MIME_TYPES = {
    ".png": "image/png",
    ".webp": "image/webp",
    ".gif": "image/gif",
    ".svg": "image/svg+xml",
}


def data_uri(data: bytes, mime: str) -> str:
    """``data`` as a base64 ``data:`` URI of type ``mime``."""
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def table(header: Sequence[str], rows: Sequence[Sequence[str]], css: str = "") -> str:
    """A table of ``header`` cells over ``rows`` of cells (HTML, escaped by the caller),
    scrolling sideways when wider than the page."""
    head = "".join(f"<th>{cell}</th>" for cell in header)
    body = "".join("<tr>" + "".join(f"<td>{cell}</td>" for cell in row) + "</tr>" for row in rows)
    return (
        f'<div class="scroll"><table class="{css}"><thead><tr>{head}</tr></thead>'
        f"<tbody>{body}</tbody></table></div>"
    )


def figure(path: Path, caption: str) -> str:
    """The image at ``path`` inlined as a figure with ``caption`` (plain text)."""
    uri = data_uri(path.read_bytes(), MIME_TYPES.get(path.suffix.lower(), "image/png"))
    text = html.escape(caption)
    return (
        f'<figure><img class="figure" src="{uri}" alt="{text}">'
        f"<figcaption>{text} <code>{html.escape(path.name)}</code></figcaption></figure>"
    )
