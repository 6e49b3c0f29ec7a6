"""The page's example quadruplets: per concept, the four videos A, AB, B and BA saved in the
report's ``examples/`` (``examples.save_examples``) as looping animations, each over its
per-frame surprise from pairs.csv with the change frame marked (``quadruplets_html``)."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from voe_lightning.report.page.animation import animated_webp, scale_of, surprise_svg
from voe_lightning.report.page.examples import VIDEOS, ExampleVideos, read_examples
from voe_lightning.report.page.markup import data_uri
from voe_lightning.report.pairs import PairResults

#: What each video of a quadruplet is; {0} and {1} are its halves' variants.
TITLES = {
    "A": "A: consistent ({0})",
    "AB": "AB: inconsistent, A's frames then B's",
    "B": "B: consistent ({1})",
    "BA": "BA: inconsistent, B's frames then A's",
}
#: Each video's pair: the half it belongs to, whether it is the inconsistent video.
HALVES = {"A": (0, False), "AB": (0, True), "B": (1, False), "BA": (1, True)}


def _pair_index(results: PairResults, concept: str, variant: str, seed: int) -> int | None:
    """The index of the pair of ``concept``, ``variant`` and ``seed`` (None: none)."""
    for index in np.flatnonzero(results.seed == seed):
        if (results.concept[index], results.variant[index]) == (concept, variant):
            return int(index)
    return None


def _video_html(
    example: ExampleVideos,
    name: str,
    results: PairResults,
    pairs: tuple[int, int],
    span: tuple[float, float],
) -> str:
    """One video of ``example``: its animation, its surprise plot (y range ``span``) and
    its caption."""
    half, inconsistent = HALVES[name]
    pair = pairs[half]
    own, partner = results.surprise_consistent[pair], results.surprise_inconsistent[pair]
    if inconsistent:
        own, partner = partner, own
    frames = example.frames[name]
    change = int(results.manipulation_frame[pair])
    width = frames.shape[2] * scale_of(frames)
    title = TITLES[name].format(*example.variants)
    total = f"S = {float(np.sum(own)):.3g}"
    if inconsistent:
        total += f", d = S({name}) − S({name[0]}) = {float(np.sum(own) - np.sum(partner)):+.3g}"
    image = data_uri(animated_webp(frames, change), "image/webp")
    return (
        f'<figure class="video"><img class="video" src="{image}" width="{width}" '
        f'data-frames="{len(frames)}" alt="{html.escape(title)}">'
        f"{surprise_svg(own, partner, change, span, width)}"
        f"<figcaption><strong>{html.escape(title)}</strong><br>{html.escape(total)}"
        "</figcaption></figure>"
    )


def _quadruplet_html(example: ExampleVideos, results: PairResults) -> str:
    """A concept's example quadruplet: a heading saying which one, and its four videos."""
    first, second = (
        _pair_index(results, example.concept, v, example.seed) for v in example.variants
    )
    heading = f"<h3>{html.escape(example.concept)}</h3>"
    if first is None or second is None:
        return heading + f"<p>pairs.csv holds no pairs of seed {example.seed} to plot.</p>"
    pairs = (first, second)
    every = np.concatenate(
        [results.surprise_consistent[list(pairs)], results.surprise_inconsistent[list(pairs)]]
    )
    span = (min(0.0, float(every.min())), float(every.max()))
    halves = [float(results.relative_surprise[pair]) for pair in pairs]
    change = int(results.manipulation_frame[first])
    about = (
        f"Seed {example.seed}, the quadruplet of median D of {example.count}: D = "
        f"{sum(halves):+.3g} (halves {halves[0]:+.3g} / {halves[1]:+.3g}). The change is "
        f"hidden at frame {change} (red mark); under each video its per-frame surprise "
        "(solid) and its pair's other video's (dashed), on one scale for all four."
    )
    videos = "".join(_video_html(example, name, results, pairs, span) for name in VIDEOS)
    return (
        f'<section class="quadruplet" data-concept="{html.escape(example.concept)}">'
        f'{heading}<p class="note">{html.escape(about)}</p><div class="videos">{videos}</div>'
        "</section>"
    )


def quadruplets_html(report_dir: Path) -> str:
    """Every example quadruplet of the report at ``report_dir``, or why there are none."""
    examples = read_examples(report_dir)
    if not examples:
        return (
            "<p>This report holds no example videos (<code>examples/</code>): they are saved "
            "from the probe store its summary.json names when the report is written.</p>"
        )
    results = PairResults.from_csv(report_dir / "pairs.csv")
    return "".join(_quadruplet_html(example, results) for example in examples)
