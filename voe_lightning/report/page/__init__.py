"""A report folder as one page a person opens: ``index.html``, self-contained and offline
(images inlined, no script, no server), written from what the folder holds, so it is decoupled
from how the report was computed. ``write_page`` saves the example quadruplets' frames
(``examples``) and writes the page (``document.write_index``); ``write_comparison`` writes the
page of several reports side by side (``analyze compare --page``).

Modules: ``examples`` (which quadruplet per concept, its frames saved from the probe store),
``animation`` (a video as an animated WebP with a timeline, its surprise as an SVG),
``quadruplets``, ``verdicts`` and ``figures`` (the page's sections), ``markdown`` (the report's
Markdown as HTML), ``markup`` (tables, figures, data URIs) and ``document`` (the pages)."""

from __future__ import annotations

from pathlib import Path

from voe_lightning.report.page.document import write_comparison, write_index
from voe_lightning.report.page.examples import save_examples

__all__ = ["save_examples", "write_comparison", "write_index", "write_page"]


def write_page(report_dir: str | Path) -> Path:
    """Save ``report_dir``'s example quadruplets (``save_examples``) and write its
    index.html (``write_index``); the page's path."""
    save_examples(report_dir)
    return write_index(report_dir)
