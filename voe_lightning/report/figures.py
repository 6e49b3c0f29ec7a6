"""The report's figures (paper Figures 4-5, Appendices B-C): d histograms, per-frame surprise
around the manipulation, the model's expected frames and the t-SNE of its time courses."""

from __future__ import annotations

import io
import math
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import numpy.typing as npt
from matplotlib.figure import Figure
from matplotlib.layout_engine import ConstrainedLayoutEngine
from matplotlib.ticker import MaxNLocator
from scipy import stats

from voe_lightning.data.store import write_whole
from voe_lightning.report.pairs import PairResults, as_numpy
from voe_lightning.specs import GENERALIZATION_VARIANT_NAMES
from voe_lightning.stats.statistics import POOLED, POOLED_VARIANTS
from voe_lightning.stats.statistics_format import BRIEF, format_p_phrase, row_text, rows_alpha

#: Histograms hide pairs whose d lies beyond this many SD from the mean (display only).
OUTLIER_SD = 3.0
CONSISTENT_COLOR, INCONSISTENT_COLOR = "tab:blue", "tab:red"


@dataclass(frozen=True, eq=False)
class PredictionExample:
    """An inconsistent probe (input frames uint8 [T, H, W, 3]) and what the model expected
    (its ``expected_frames``, e.g. the VRNN's decoded prior means; float [T, 3, H, W] in
    [0, 1])."""

    concept: str
    variant: str
    seed: int
    manipulation_frame: int
    frames: np.ndarray
    expected: np.ndarray


def save_figure(figure: Figure, path: str | Path) -> Path:
    """Write ``figure`` at exactly ``path`` (no suffix added: a PNG unless its suffix names
    another format matplotlib writes), whole (``store.write_whole``), say so, and
    return the path."""
    path = Path(path)
    if path.is_dir():  # write_whole would replace an empty folder with the file
        raise ValueError(
            f"cannot write a figure as {path}: it is a folder, and a figure is one file; "
            f"give a file path, e.g. {path / 'figure.png'}"
        )
    kind = path.suffix[1:].lower() or "png"
    if kind not in figure.canvas.get_supported_filetypes():
        raise ValueError(
            f"cannot write a figure as {path}: {path.suffix!r} is no image format "
            f"matplotlib writes; use .png, or one of "
            f"{', '.join(sorted(figure.canvas.get_supported_filetypes()))}"
        )
    image = io.BytesIO()
    figure.savefig(image, format=kind, dpi=110)
    write_whole({path: image.getvalue()})
    print(f"wrote {path}")
    return path


def panel_grid(
    count: int, width: float, height: float, max_cols: int = 4
) -> tuple[Figure, npt.NDArray[np.object_]]:
    """A constrained-layout figure with ``count`` visible panels of width x height inches in
    rows of at most ``max_cols``: (figure, axes [count])."""
    cols = max(1, min(max_cols, count))
    rows = math.ceil(count / cols)
    figure = Figure(figsize=(width * cols, height * rows), layout="constrained")
    axes = figure.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[count:]:
        ax.set_visible(False)
    return figure, axes[:count]


def _stats_text(row: Mapping[str, Any]) -> str:
    if row["t"] is None:
        return f"n = {row['n']}: no test"
    text = row_text(row, BRIEF)
    star = " *" if text.significant else ""
    return (
        f"M = {text.mean}\n{text.t}, {text.p_phrase}{star}\n"
        f"d_z = {text.d_z}, acc. = {text.accuracy}"
    )


def histogram_figure(results: PairResults, rows: Sequence[Mapping[str, Any]]) -> Figure:
    """Distribution of d per concept/variant with the test result printed on each panel
    (paper Figure 4); pairs beyond 3 SD of the mean are hidden for display only."""
    groups = results.groups()
    figure, axes = panel_grid(len(groups), 4.2, 3.2)
    by_key = {(row["concept"], row["variant"]): row for row in rows}
    for ax, (concept, variant, pairs) in zip(axes, groups):
        d = pairs.relative_surprise
        sd = d.std(ddof=1) if d.size > 1 else 0.0
        shown = d[np.abs(d - d.mean()) <= OUTLIER_SD * sd] if sd > 0 else d
        row = by_key[(concept, variant)]
        color = "tab:green" if row.get("significant") else "tab:gray"
        counts, _, _ = ax.hist(
            shown,
            bins=max(5, min(40, int(np.sqrt(shown.size)) * 2)),
            color=color,
            alpha=0.75,
            edgecolor="white",
        )
        ax.set_ylim(0, max(counts.max(), 1) * 1.75)  # headroom for the statistics box
        ax.axvline(0.0, color="black", linewidth=1)
        ax.axvline(d.mean(), color="black", linewidth=1, linestyle="--")
        ax.set_title(f"{concept} / {variant}", fontsize=10)
        ax.set_xlabel("d = S(inconsistent) - S(consistent)")
        ax.set_ylabel("probe pairs")
        hidden = d.size - shown.size
        ax.text(
            0.98,
            0.97,
            _stats_text(row) + f"\n{hidden} of {d.size} beyond 3 SD hidden",
            transform=ax.transAxes,
            ha="right",
            va="top",
            fontsize=8,
            bbox=dict(boxstyle="round", facecolor="white", alpha=0.85, edgecolor="0.7"),
        )
    title = (
        "Relative surprise per probe pair (dashed: mean of all pairs). Outliers > 3 SD "
        "removed for display only; tests use all pairs; "
        f"* p < {rows_alpha(rows):g} one-tailed"
    )
    figure.suptitle(textwrap.fill(title, width=int(14 * figure.get_figwidth())), fontsize=10)
    return figure


def _aligned(surprise: np.ndarray, manipulation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame surprise [N, T] re-indexed by frame - manipulation_frame: (offsets, [N, L]
    with NaN where a pair has no such frame)."""
    n, frames = surprise.shape
    first = -int(manipulation.max())
    last = frames - 1 - int(manipulation.min())
    offsets = np.arange(first, last + 1)
    aligned = np.full((n, offsets.size), np.nan)
    for i in range(n):
        start = -int(manipulation[i]) - first
        aligned[i, start : start + frames] = surprise[i]
    return offsets, aligned


def _mean_and_band(aligned: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    count = np.sum(~np.isnan(aligned), axis=0)
    mean = np.nanmean(np.where(count > 0, aligned, 0.0), axis=0)
    half = np.full(mean.shape, np.nan)
    ok = count >= 2
    if ok.any():
        sd = np.nanstd(aligned[:, ok], axis=0, ddof=1)
        half[ok] = stats.t.ppf(0.975, count[ok] - 1) * sd / np.sqrt(count[ok])
    return mean, half


def per_frame_figure(results: PairResults) -> Figure:
    """Mean per-frame surprise of consistent vs inconsistent probes per concept/variant,
    aligned at the manipulation frame, with 95% t confidence bands; ticks on whole frames, each
    title on two lines (concept, then variant) so that no long variant name is cut."""
    groups = results.groups()
    figure, axes = panel_grid(len(groups), 4.2, 3.0)
    for ax, (concept, variant, pairs) in zip(axes, groups):
        for label, surprise, color in (
            ("consistent", pairs.surprise_consistent, CONSISTENT_COLOR),
            ("inconsistent", pairs.surprise_inconsistent, INCONSISTENT_COLOR),
        ):
            offsets, aligned = _aligned(surprise, pairs.manipulation_frame)
            mean, half = _mean_and_band(aligned)
            ax.plot(offsets, mean, color=color, marker="o", markersize=3, label=label)
            ax.fill_between(offsets, mean - half, mean + half, color=color, alpha=0.2, linewidth=0)
        ax.axvline(0, color="black", linestyle="--", linewidth=1)
        ax.set_title(f"{concept}\n{variant} (n = {len(pairs)})", fontsize=10)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("frame relative to manipulation (dashed)")
        ax.set_ylabel("surprise per frame (the model's)")
        ax.legend(fontsize=8, loc="upper left")
    figure.suptitle("Mean per-frame surprise with 95% confidence bands", fontsize=10)
    return figure


def _frame_indices(num_frames: int, max_frames: int) -> np.ndarray:
    if num_frames <= max_frames:
        return np.arange(num_frames)
    return np.unique(np.linspace(0, num_frames - 1, max_frames).round().astype(int))


def predictions_figure(examples: Sequence[PredictionExample], max_frames: int = 15) -> Figure:
    """Input frames of inconsistent probes above the model's expected frames (decoded prior
    means), as in the paper's Figure 5 and Appendix C; the manipulation frame is framed red."""
    if not examples:
        raise ValueError("predictions_figure needs at least one PredictionExample")
    indices = _frame_indices(examples[0].frames.shape[0], max_frames)
    figure = Figure(figsize=(0.9 * len(indices) + 0.6, 2.1 * len(examples)), layout="constrained")
    engine = cast(ConstrainedLayoutEngine, figure.get_layout_engine())
    engine.set(w_pad=0.01, h_pad=0.01, wspace=0.01, hspace=0.01)
    subfigures = figure.subfigures(len(examples), 1, squeeze=False)[:, 0]
    for subfigure, example in zip(subfigures, examples):
        frames = as_numpy(example.frames, np.uint8)
        expected = np.clip(as_numpy(example.expected, np.float32), 0.0, 1.0).transpose(0, 2, 3, 1)
        if frames.shape[:3] != expected.shape[:3]:
            raise ValueError(f"frames {frames.shape} and expected {expected.shape} disagree")
        axes = subfigure.subplots(2, len(indices), squeeze=False)
        for column, t in enumerate(indices):
            for row, image in enumerate((frames[t], expected[t])):
                ax = axes[row, column]
                ax.imshow(image, interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                if t == example.manipulation_frame:
                    for spine in ax.spines.values():
                        spine.set_edgecolor("red")
                        spine.set_linewidth(2.5)
            axes[0, column].set_title(
                f"t={t}", fontsize=8, color="red" if t == example.manipulation_frame else "black"
            )
        axes[0, 0].set_ylabel("input", fontsize=9)
        axes[1, 0].set_ylabel("expected", fontsize=9)
        title = (
            f"{example.concept} / {example.variant}, seed {example.seed}: inconsistent "
            "probe (top) and what the model expected from the frames before (bottom); red: "
            "manipulation frame"
        )
        subfigure.suptitle(textwrap.fill(title, width=int(14 * figure.get_figwidth())), fontsize=9)
    return figure


def _arrowhead(ax: Any, curve: np.ndarray, color: str) -> None:
    """An arrowhead at the curve's last point, pointing along its last non-zero step."""
    moved = np.flatnonzero(np.any(curve[:-1] != curve[-1], axis=1))
    if moved.size:
        ax.annotate(
            "",
            xy=curve[-1],
            xytext=curve[moved[-1]],
            arrowprops=dict(
                arrowstyle="-|>", color=color, lw=1.5, mutation_scale=20, shrinkA=0, shrinkB=0
            ),
        )


#: Panel titles of the t-SNE figure by trajectory kind (others: the kind, capitalised).
TSNE_TITLES = {"prior": "Priors", "memory": "Memory"}
#: Appendix B colours: pair i's consistent and inconsistent curve.
TSNE_CONSISTENT_COLORS = ("cyan", "blue", "teal", "navy")
TSNE_INCONSISTENT_COLORS = ("red", "magenta", "darkred", "purple")


def _tsne_kinds(trajectories: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The trajectory kinds, checked the same for both videos."""
    kinds = list(trajectories.get("consistent", {}))
    if not kinds or kinds != list(trajectories.get("inconsistent", {})):
        raise KeyError(
            "trajectories need the same kinds for both videos, e.g. "
            "dict(consistent=dict(prior, memory), inconsistent=dict(prior, memory)); "
            f"got { ({video: list(v) for video, v in trajectories.items()}) }"
        )
    return kinds


def _tsne_points(trajectories: Mapping[str, Mapping[str, Any]], kind: str) -> np.ndarray:
    """One kind's courses of both videos as points [2 N T, features], for t-SNE to embed."""
    consistent = as_numpy(trajectories["consistent"][kind], np.float64)
    inconsistent = as_numpy(trajectories["inconsistent"][kind], np.float64)
    if inconsistent.shape != consistent.shape:
        raise ValueError(
            f"{kind}: consistent {consistent.shape} and inconsistent "
            f"{inconsistent.shape} trajectories disagree"
        )
    n, frames = consistent.shape[:2]
    return np.concatenate([consistent, inconsistent]).reshape(2 * n * frames, -1)


def tsne_unfit(trajectories: Mapping[str, Mapping[str, Any]]) -> str | None:
    """Why t-SNE cannot embed these trajectories (NaN or infinite values; squared distances 0,
    or beyond float64), or None: the report then skips the figure, never the statistics."""
    for kind in _tsne_kinds(trajectories):
        points = _tsne_points(trajectories, kind)
        if not np.isfinite(points).all():
            return f"the model's {kind!r} trajectories hold NaN or infinite values"
        ranges = np.ptp(points, axis=0)
        with np.errstate(over="ignore", under="ignore"):
            square = float(np.square(ranges).sum())
        if not 0.0 < square < math.inf:
            return (
                f"the model's {kind!r} trajectories differ by at most {ranges.max():g} over "
                "every frame of every probe; t-SNE embeds points whose squared distances "
                "lie above 0 and within float64"
            )
    return None


def tsne_figure(
    trajectories: Mapping[str, Mapping[str, Any]],
    labels: Sequence[str] | None = None,
    seed: int = 0,
) -> Figure:
    """t-SNE of the model's time courses (paper Appendix B: prior and memory), one panel per
    kind. ``trajectories`` maps "consistent" and "inconsistent" to dict(kind -> [N, T, ...])
    for N probe pairs, both with the same kinds; pair i is drawn cyan/red, blue/magenta, ...
    (consistent/inconsistent), each curve from a dot (first frame) to an arrowhead (last)."""
    from sklearn.manifold import TSNE

    kinds = _tsne_kinds(trajectories)
    figure = Figure(figsize=(5.5 * len(kinds), 5), layout="constrained")
    axes = np.atleast_1d(figure.subplots(1, len(kinds)))
    for ax, kind in zip(axes, kinds):
        title = TSNE_TITLES.get(kind, kind.capitalize())
        points = _tsne_points(trajectories, kind)
        n, frames = np.shape(trajectories["consistent"][kind])[:2]
        perplexity = min(30.0, (points.shape[0] - 1) / 3.0)
        method = "exact" if points.shape[0] <= 2000 else "barnes_hut"  # exact: faster when small
        embedded = (
            TSNE(
                n_components=2, perplexity=perplexity, init="pca", method=method, random_state=seed
            )
            .fit_transform(points)
            .reshape(2, n, frames, 2)
        )
        # Consistent curves wide and pale underneath, so a shared stretch shows both colours.
        for video, palette, name, width, alpha in (
            (0, TSNE_CONSISTENT_COLORS, "consistent", 5.0, 0.45),
            (1, TSNE_INCONSISTENT_COLORS, "inconsistent", 1.6, 1.0),
        ):
            for i in range(n):
                color = palette[i % len(palette)]
                curve = embedded[video, i]
                label = f"{labels[i] if labels else f'pair {i + 1}'} {name}"
                ax.plot(
                    curve[:, 0],
                    curve[:, 1],
                    color=color,
                    linewidth=width,
                    alpha=alpha,
                    label=label,
                    solid_capstyle="round",
                )
                ax.plot(*curve[0], "o", color=color, markersize=6)
                _arrowhead(ax, curve, color)
        ax.set_title(f"{title} (t-SNE; dot = first frame, arrow = last)", fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
    axes[-1].legend(fontsize=8, loc="best")
    figure.suptitle(
        "Object persistence probes: consistent blue/cyan, inconsistent red/magenta", fontsize=10
    )
    return figure


def cue_scatter_figure(
    results: PairResults, cue_audit: Any, correlation_rows: Sequence[Mapping[str, Any]]
) -> Figure | None:
    """Per pair, the model's relative surprise against the difference of the frame-local cue
    it tracks most (largest |r| of ``CueAudit.model_correlations``), one panel per group a
    verdict reads (pooled rows; every variant of a concept without one), points coloured by
    variant: a cue-follower lines up along the cue, its variants on either side of 0. A pooled
    panel plots the pairs its r counts, the pooled variants' (not, e.g., continuity's
    ``paper`` pairs, reported beside)."""
    from voe_lightning.audit.cues import CUE_TITLES, tracked_cues

    pooled = {r["concept"] for r in correlation_rows if r["variant"] == POOLED}
    panels = {
        key: row
        for key, row in tracked_cues(correlation_rows).items()
        if key[1] == POOLED or (key[0] not in pooled and key[1] not in GENERALIZATION_VARIANT_NAMES)
    }
    if not panels:
        return None
    concepts, variants = np.array(results.concept), np.array(results.variant)
    d = results.relative_surprise
    figure, axes = panel_grid(len(panels), 3.6, 3.2)
    for ax, ((concept, variant), row) in zip(axes, panels.items()):
        cue = row["cue"]
        cue_d = cue_audit.scores["inconsistent"][cue] - cue_audit.scores["consistent"][cue]
        chosen = (concepts == concept) & (
            np.isin(variants, POOLED_VARIANTS) if variant == POOLED else variants == variant
        )
        for name in dict.fromkeys(variants[chosen]):
            points = chosen & (variants == name)
            ax.scatter(cue_d[points], d[points], s=10, alpha=0.7, label=name)
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.axvline(0.0, color="black", linewidth=0.8, linestyle=":")
        ax.set_title(
            f"{concept} / {variant}\nr = {row['r']:+.2f}, "
            f"{format_p_phrase(row['p_two_sided'])} (two-sided)",
            fontsize=9,
        )
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3))
        ax.set_xlabel(f"{CUE_TITLES[cue]}: score(inc.) - score(con.)", fontsize=8)
        ax.set_ylabel("model: S(inc.) - S(con.)", fontsize=8)
        ax.legend(fontsize=7, loc="best")
    figure.suptitle(
        "Does surprise track a physics-blind cue? Each point a probe pair "
        "(the frame-local cue with the largest |r| per panel)"
    )
    return figure


def _save(figure: Figure, path: Path) -> None:
    figure.savefig(path, dpi=110)


def write_figures(
    results: PairResults,
    rows: Sequence[Mapping[str, Any]],
    report_dir: Path,
    predictions: Sequence[PredictionExample] | None = None,
    trajectories: Mapping[str, Any] | None = None,
    trajectory_labels: Sequence[str] | None = None,
    seed: int = 0,
    cue_audit: Any = None,
    correlation_rows: Sequence[Mapping[str, Any]] | None = None,
) -> None:
    """Write histograms.png and surprise_per_frame.png into ``report_dir``, and from
    ``predictions`` predictions_<concept>.png, from ``trajectories`` tsne_object_persistence.png,
    from ``cue_audit`` and its ``correlation_rows`` cue_scatter.png."""
    _save(histogram_figure(results, rows), report_dir / "histograms.png")
    if cue_audit is not None and correlation_rows is not None:
        scatter = cue_scatter_figure(results, cue_audit, correlation_rows)
        if scatter is not None:
            _save(scatter, report_dir / "cue_scatter.png")
    _save(per_frame_figure(results), report_dir / "surprise_per_frame.png")
    by_concept: dict[str, list[PredictionExample]] = {}
    for example in predictions or ():
        by_concept.setdefault(example.concept, []).append(example)
    for concept, examples in by_concept.items():
        _save(predictions_figure(examples), report_dir / f"predictions_{concept}.png")
    if trajectories is not None:
        _save(
            tsne_figure(trajectories, trajectory_labels, seed=seed),
            report_dir / "tsne_object_persistence.png",
        )
