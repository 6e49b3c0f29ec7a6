"""Which figures of a report folder a page shows, in what order and under what caption
(``report_figures``), and the section that inlines them (``figures_html``)."""

from __future__ import annotations

from pathlib import Path

from voe_lightning import specs
from voe_lightning.report.page.markup import figure

#: Captions of the figures the report writes, in the order the page shows them.
CAPTIONS = {
    "histograms.png": "Relative surprise per probe pair, with each group's test (paper Figure 4).",
    "surprise_per_frame.png": "Mean per-frame surprise around the manipulation, consistent "
    "and inconsistent probes, with 95% confidence bands.",
    **{
        f"predictions_{concept}.png": f"{concept}: an inconsistent probe above the frames the "
        "model expected (paper Figure 5; the manipulation frame framed red)."
        for concept in specs.CONCEPTS
    },
    "tsne_object_persistence.png": "t-SNE of the model's time courses on object-persistence "
    "pairs (paper Appendix B).",
    "cue_scatter.png": "Per pair, the model's relative surprise against the difference of the "
    "physics-blind cue it tracks most.",
}


def report_figures(report_dir: Path) -> list[tuple[Path, str]]:
    """(path, caption) of each PNG in ``report_dir``: the report's own in ``CAPTIONS`` order,
    then any other by name."""
    found = {path.name: path for path in sorted(report_dir.glob("*.png"))}
    known = [(found[name], caption) for name, caption in CAPTIONS.items() if name in found]
    others = [
        (path, path.stem.replace("_", " ")) for name, path in found.items() if name not in CAPTIONS
    ]
    return known + others


def figures_html(report_dir: Path) -> str:
    """Every figure of the report at ``report_dir``, inlined."""
    figures = report_figures(report_dir)
    if not figures:
        return "<p>This report has no figures.</p>"
    return "".join(figure(path, caption) for path, caption in figures)
