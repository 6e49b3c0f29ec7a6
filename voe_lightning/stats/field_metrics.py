"""The field's metric set (docs/architecture.md §6), as the V-JEPA intuitive-physics evaluation
(Garrido et al. 2025, arXiv:2502.11831; its IntPhys 2 form by Bordes et al. 2025) reports it,
from each matched pair's per-frame surprise [N, T] of its possible (consistent) and impossible
(inconsistent) video. A video's surprise is reduced over its frames three ways (``REDUCTIONS``:
the sum, the paper's and our statistics'; the mean; the max):

- relative accuracy per reduction: the share of pairs with S(possible) < S(impossible), a tie
  counting half (chance is 0.5), with the number of ties;
- absolute accuracy: a video is called impossible when its max surprise exceeds the threshold,
  the 90th percentile (numpy's linear interpolation) of the possible videos' max surprise; the
  share of videos, possible and impossible, called right;
- AUROC per reduction for telling impossible videos from possible ones, ties counting half.

The one home of these numbers: our probe reports (summary.json's ``field_metrics``), IntPhys 2
(``benchmarks.metrics.intphys2_metrics``) and the quadruplet benchmarks (IntPhys, DeepMind
Physical Concepts: ``benchmarks.metrics.quadruplet_metrics``) compute them here, and
``format_field_metrics`` writes them as Markdown everywhere. A windowed model's sweep over
context length is one set per context length (``context_sweep``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

import numpy as np

from voe_lightning.stats.statistics import ranked_auroc
from voe_lightning.stats.statistics_format import format_number
from voe_lightning.stats.surprise_window import SurpriseWindow, video_surprise

#: The ways a video's per-frame surprise is reduced to one number, each with its metrics.
REDUCTIONS = ("sum", "mean", "max")
#: Percentile of the possible videos' max surprise above which a video is called impossible.
PERCENTILE = 90.0


def reduce_surprise(per_frame: Any, reduction: str) -> np.ndarray:
    """Each video's surprise [N] from per-frame surprise [N, T] by one of ``REDUCTIONS`` (the
    sum through ``surprise_window.video_surprise``, the one place a video's total is made)."""
    per_frame = np.asarray(per_frame, dtype=np.float64)
    if reduction == "sum":
        return cast(np.ndarray, video_surprise(per_frame))
    if reduction == "mean":
        return cast(np.ndarray, per_frame.mean(axis=-1))
    if reduction == "max":
        return cast(np.ndarray, per_frame.max(axis=-1))
    raise ValueError(f"unknown surprise reduction {reduction!r}; valid: {', '.join(REDUCTIONS)}")


def relative_accuracy(surprise_possible: Any, surprise_impossible: Any) -> tuple[float, int]:
    """Share of pairs whose possible video is less surprising than its impossible one (a tie
    counts half), and the number of ties."""
    possible = np.asarray(surprise_possible, dtype=np.float64).ravel()
    impossible = np.asarray(surprise_impossible, dtype=np.float64).ravel()
    if possible.shape != impossible.shape or possible.size == 0:
        raise ValueError(
            f"need one possible and one impossible surprise per pair (>0 pairs), got "
            f"{possible.size} and {impossible.size}"
        )
    ties = int((possible == impossible).sum())
    return float(((possible < impossible).sum() + 0.5 * ties) / possible.size), ties


def surprise_threshold(max_surprise_possible: Any, percentile: float = PERCENTILE) -> float:
    """The ``percentile``-th percentile of the possible videos' max surprise: above it a video
    is called impossible."""
    values = np.asarray(max_surprise_possible, dtype=np.float64).ravel()
    if values.size == 0 or not np.isfinite(values).all():
        raise ValueError(
            f"a threshold needs finite max surprise of >0 possible videos, got {values.size} values"
        )
    return float(np.percentile(values, percentile))


def absolute_accuracy(max_surprise: Any, is_possible: Any, threshold: float) -> float:
    """Share of videos called right: impossible when max surprise > ``threshold``."""
    called_possible = np.asarray(max_surprise, dtype=np.float64).ravel() <= threshold
    return float((called_possible == np.asarray(is_possible, dtype=bool).ravel()).mean())


def _per_frame_pairs(frames_possible: Any, frames_impossible: Any) -> tuple[np.ndarray, np.ndarray]:
    possible = np.asarray(frames_possible, dtype=np.float64)
    impossible = np.asarray(frames_impossible, dtype=np.float64)
    if possible.ndim != 2 or possible.shape != impossible.shape or possible.shape[0] == 0:
        raise ValueError(
            f"per-frame surprise must be [N, T] on both sides (N > 0), got "
            f"{possible.shape} and {impossible.shape}"
        )
    return possible, impossible


def after(per_frame: np.ndarray, first_frame: Any) -> np.ndarray:
    """Per-frame surprise [N, T] with the frames before each pair's ``first_frame`` [N] set to
    -inf, so that a max reads the frames from there on only (the window of every frame from
    there, ``SurpriseWindow.frame_weights``)."""
    first = np.asarray(first_frame, dtype=np.int64).reshape(-1, 1)
    if (
        first.shape[0] != per_frame.shape[0]
        or (first < 0).any()
        or (first >= per_frame.shape[1]).any()
    ):
        raise ValueError(
            f"first_frame must be one frame index in [0, {per_frame.shape[1] - 1}] per pair "
            f"({per_frame.shape[0]}), got {first.ravel().tolist()}"
        )
    steps = per_frame.shape[1]
    inside = SurpriseWindow(steps).frame_weights(steps, first.ravel()) > 0
    return np.where(inside, per_frame, -np.inf)


def field_metrics(
    frames_possible: Any,
    frames_impossible: Any,
    threshold: float | None = None,
    percentile: float = PERCENTILE,
    max_from: Any = None,
) -> dict[str, Any]:
    """The metric set (module docstring) of matched pairs from per-frame surprise [N, T] of
    each pair's possible and impossible video: ``relative_accuracy_<r>``, ``ties_<r>`` and
    ``auroc_<r>`` per reduction r, ``absolute_accuracy`` at ``threshold`` (None: the
    ``percentile``-th percentile of these possible videos' max surprise) and that
    ``threshold``. ``max_from`` [N] (None: every frame, as the field takes it) is each pair's
    first frame the max reads: from where its two videos differ, the max of a probe pair is
    not the same frame's in both (before, the pair is one video)."""
    possible, impossible = _per_frame_pairs(frames_possible, frames_impossible)
    if max_from is not None:
        possible_max, impossible_max = after(possible, max_from), after(impossible, max_from)
    else:
        possible_max, impossible_max = possible, impossible
    if threshold is None:
        threshold = surprise_threshold(possible_max.max(axis=-1), percentile)
    result: dict[str, Any] = {"n_pairs": possible.shape[0]}
    for reduction in REDUCTIONS:
        sides = (possible_max, impossible_max) if reduction == "max" else (possible, impossible)
        low, high = (reduce_surprise(side, reduction) for side in sides)
        result[f"relative_accuracy_{reduction}"], result[f"ties_{reduction}"] = relative_accuracy(
            low, high
        )
        result[f"auroc_{reduction}"] = ranked_auroc(high, low)
    maxima = np.concatenate([possible_max.max(axis=-1), impossible_max.max(axis=-1)])
    labels = np.arange(maxima.size) < possible.shape[0]
    result["absolute_accuracy"] = absolute_accuracy(maxima, labels, threshold)
    result["threshold"] = float(threshold)
    return result


def context_sweep(
    per_context: Mapping[int, tuple[Any, Any]], percentile: float = PERCENTILE
) -> dict[int, dict[str, Any]]:
    """``field_metrics`` per context length of a windowed model, from {context length:
    (per-frame surprise of the possible videos, of the impossible ones)}; each context length
    gets its own threshold, as each is its own model of the videos."""
    if not per_context:
        raise ValueError("a context sweep needs at least one context length")
    return {
        int(context): field_metrics(*sides, percentile=percentile)
        for context, sides in sorted(per_context.items())
    }


def format_field_metrics(
    rows: Mapping[str, Mapping[str, Any]], label: str = "group", max_after_change: bool = False
) -> str:
    """The metric set as a Markdown table, one row per {name: ``field_metrics`` result}, and a
    line saying what the columns are (``max_after_change``: that the max read the frames after
    each pair's change, ``field_metrics``'s ``max_from``); ``label`` heads the names' column. A
    row without a metric (a note instead) shows n/a there."""
    reductions = " | ".join(REDUCTIONS)
    header = (
        f"| {label} | n | relative accuracy: {reductions} | absolute accuracy "
        f"| threshold | AUROC: {reductions} |"
    )
    lines = [header, "|" + "---|" * (4 + 2 * len(REDUCTIONS))]
    for name, metrics in rows.items():
        relative = " | ".join(
            format_number(metrics.get(f"relative_accuracy_{r}"), ".1%") for r in REDUCTIONS
        )
        area = " | ".join(format_number(metrics.get(f"auroc_{r}"), ".3f") for r in REDUCTIONS)
        lines.append(
            f"| {name} | {metrics['n_pairs']} | {relative} "
            f"| {format_number(metrics.get('absolute_accuracy'), '.1%')} "
            f"| {format_number(metrics.get('threshold'), '.3g')} | {area} |"
        )
    over = (
        "max over the frames after the change (before it a pair's two videos are one, and "
        "their max is the same frame's)"
        if max_after_change
        else "max over frames"
    )
    lines += [
        "",
        "Relative accuracy: share of pairs whose possible (consistent) video is less "
        f"surprising than its impossible one, surprise the sum, mean or {over}, "
        "ties half; absolute accuracy: share of videos called right when a video is "
        "impossible if its max surprise exceeds the threshold, the "
        f"{PERCENTILE:g}th percentile of the possible videos' max surprise; AUROC of sum, "
        "mean and max surprise for telling impossible videos from possible ones "
        "(Garrido et al. 2025).",
    ]
    return "\n".join(lines) + "\n"
