"""A video as the page shows it: a looping animated WebP of its frames, enlarged, over a
timeline strip that marks the current frame and the change frame (``animated_webp``), and its
per-frame surprise as a small inline SVG whose frames line up with the strip's
(``surprise_svg``)."""

from __future__ import annotations

import html
import io
from collections.abc import Sequence
from typing import cast

import numpy as np
from PIL import Image

#: Width in pixels the page draws a video at (frames are enlarged by a whole factor to it).
VIDEO_WIDTH = 192
#: Height of the timeline strip under a video's frames, and of its change mark.
STRIP, MARK = 8, 3
#: Milliseconds a frame is shown; the last one is held longer before the loop restarts.
FRAME_MS, LAST_FRAME_MS = 250, 1000
CHANGE_COLOR = (214, 39, 40)
PAST, NOW, FUTURE = (150, 150, 150), (255, 255, 255), (60, 60, 60)


def scale_of(frames: np.ndarray) -> int:
    """The whole factor that enlarges ``frames`` [T, H, W, 3] to about ``VIDEO_WIDTH``."""
    return cast(int, max(1, VIDEO_WIDTH // frames.shape[2]))


def _cells(count: int, width: int) -> list[tuple[int, int]]:
    """[start, stop) in pixels of each of ``count`` frames' cells across ``width``."""
    edges = np.round(np.linspace(0, width, count + 1)).astype(int)
    return list(zip(edges[:-1].tolist(), edges[1:].tolist()))


def _strip(count: int, width: int, current: int, change: int) -> np.ndarray:
    """The timeline under frame ``current`` of ``count``: frames shown so far, the current
    one, those to come, and a mark over the change frame."""
    strip = np.zeros((STRIP, width, 3), np.uint8)
    for frame, (start, stop) in enumerate(_cells(count, width)):
        color = PAST if frame < current else NOW if frame == current else FUTURE
        strip[MARK:, start : max(start + 1, stop - 1)] = color
        if frame == change:
            strip[:MARK, start:stop] = CHANGE_COLOR
    return strip


def animated_webp(frames: np.ndarray, change: int) -> bytes:
    """A lossless looping animated WebP of ``frames`` [T, H, W, 3] uint8, enlarged by
    ``scale_of`` with no smoothing, each over its ``_strip`` (change frame ``change``)."""
    scale = scale_of(frames)
    big = np.repeat(np.repeat(frames, scale, axis=1), scale, axis=2)
    count, width = len(frames), big.shape[2]
    images = [
        Image.fromarray(np.concatenate([frame, _strip(count, width, t, change)]))
        for t, frame in enumerate(big)
    ]
    buffer = io.BytesIO()
    images[0].save(
        buffer,
        format="WEBP",
        save_all=True,
        append_images=images[1:],
        duration=[FRAME_MS] * (count - 1) + [LAST_FRAME_MS],
        loop=0,
        lossless=True,
    )
    return buffer.getvalue()


def _points(
    values: Sequence[float], width: int, top: float, bottom: float, span: tuple[float, float]
) -> str:
    """SVG polyline points of ``values``, one per frame cell's centre, scaled so ``span``
    (low, high) runs from ``bottom`` to ``top``."""
    low, high = span
    cells = _cells(len(values), width)
    scale = (bottom - top) / (high - low) if high > low else 0.0
    return " ".join(
        f"{(start + stop) / 2:.1f},{bottom - (value - low) * scale:.1f}"
        for (start, stop), value in zip(cells, values)
    )


def _tick(value: float) -> str:
    """A y-axis label: three significant figures."""
    return f"{value:.3g}"


def surprise_svg(
    surprise: Sequence[float],
    partner: Sequence[float],
    change: int,
    span: tuple[float, float],
    width: int,
    height: int = 92,
) -> str:
    """An inline SVG of a video's per-frame ``surprise`` (solid, dark) and its pair's other
    video's (``partner``: dashed, light, drawn on top so that where the two coincide both
    show), on the y range ``span`` shared by a quadruplet's four plots: a y axis with that
    range's ends labelled, a frame axis with a tick per frame (its first, change and last
    frames numbered), a dashed line at the ``change`` frame and a legend; frames aligned with
    ``animated_webp``'s strip."""
    top, bottom = 10.0, height - 34.0
    cells = _cells(len(surprise), width)
    start, stop = cells[change]
    middle = (start + stop) / 2
    low, high = span
    label = html.escape(
        f"surprise per frame from {low:.3g} to {high:.3g} (the quadruplet's range); solid: "
        "this video, dashed: its pair's other video"
    )
    ticks = "".join(
        f'<line x1="{(a + b) / 2:.1f}" y1="{bottom:.1f}" x2="{(a + b) / 2:.1f}" '
        f'y2="{bottom + 3:.1f}" stroke="#666"/>'
        for a, b in cells
    )
    numbered = sorted({0, change, len(cells) - 1})
    numbers = "".join(
        f'<text x="{(cells[f][0] + cells[f][1]) / 2:.1f}" y="{bottom + 12:.1f}" font-size="9" '
        f'text-anchor="middle" fill="#444">{f}</text>'
        for f in numbered
    )
    legend_y = height - 6
    return (
        f'<svg class="surprise" width="{width}" height="{height}" viewBox="0 0 {width} {height}" '
        f'role="img" aria-label="{label}">'
        f'<rect x="0" y="0" width="{width}" height="{bottom + 1:.1f}" fill="#fafafa"/>'
        f'<line x1="0.5" y1="{top:.1f}" x2="0.5" y2="{bottom:.1f}" stroke="#666"/>'
        f'<line x1="0" y1="{bottom:.1f}" x2="{width}" y2="{bottom:.1f}" stroke="#666"/>'
        f"{ticks}{numbers}"
        f'<text x="3" y="{top + 3:.1f}" font-size="9" fill="#444">{_tick(high)}</text>'
        f'<text x="3" y="{bottom - 2:.1f}" font-size="9" fill="#444">{_tick(low)}</text>'
        f'<text x="{width - 2}" y="{bottom + 22:.1f}" font-size="9" text-anchor="end" '
        'fill="#444">frame</text>'
        f'<line x1="{middle:.1f}" y1="0" x2="{middle:.1f}" y2="{bottom:.1f}" stroke="#d62728" '
        'stroke-dasharray="3,2"/>'
        f'<text x="{middle + 3:.1f}" y="9" font-size="9" fill="#d62728">change</text>'
        f'<polyline points="{_points(surprise, width, top, bottom, span)}" fill="none" '
        'stroke="#1f3b73" stroke-width="2"/>'
        f'<polyline points="{_points(partner, width, top, bottom, span)}" fill="none" '
        'stroke="#9ab" stroke-width="1.5" stroke-dasharray="4,3"/>'
        f'<line x1="2" y1="{legend_y - 3}" x2="16" y2="{legend_y - 3}" stroke="#1f3b73" '
        'stroke-width="2"/>'
        f'<text x="19" y="{legend_y}" font-size="9" fill="#444">this video</text>'
        f'<line x1="72" y1="{legend_y - 3}" x2="86" y2="{legend_y - 3}" stroke="#9ab" '
        'stroke-width="1.5" stroke-dasharray="4,3"/>'
        f'<text x="89" y="{legend_y}" font-size="9" fill="#444">its pair\'s other</text>'
        "</svg>"
    )
