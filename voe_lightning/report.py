"""The paper's Results section for one run (paper §5, Figures 4-5, Appendices B-C): per
concept/variant paired tests, per-pair surprise, and the figures, written to
``<run dir>/voe_report/`` by ``write_report`` or, during ``test``, by ``VOEReportCallback``.

Files: ``summary.json``/``summary.csv``/``summary.md`` (one row per concept/variant, a
``pooled`` row per concept with a counterbalanced pair, and each concept's VOE verdict),
``pairs.csv`` (one row per probe pair, with per-frame surprise, so anyone can redo the
statistics), ``cues.md``/``cues.csv``/``cues.json`` (the cue audit on the same pairs, beside the
model's rows; see ``voe_lightning.cues``), ``histograms.png``, ``surprise_per_frame.png``,
``predictions_<concept>.png`` and ``tsne_object_persistence.png``.
"""

from __future__ import annotations

import csv
import json
import math
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lightning.pytorch import Callback, LightningModule, Trainer
from lightning.pytorch.utilities import rank_zero_warn
from matplotlib.figure import Figure
from scipy import stats

from voe_lightning import cues
from voe_lightning.model.base import SurpriseModel, video_inputs
from voe_lightning.model.module import VOEModel
from voe_lightning.specs import CONCEPTS, VARIANTS
from voe_lightning.statistics import (
    PairedTestResult,
    concept_verdicts,
    pair_groups,
    paired_test,
)

__all__ = [
    "PROBE_OUTPUT_KEYS",
    "PairResults",
    "PredictionExample",
    "VOEReportCallback",
    "format_markdown",
    "histogram_figure",
    "per_frame_figure",
    "predictions_figure",
    "summarize",
    "tsne_figure",
    "write_report",
]

#: Keys of the dict that ``VOEModel.probe_step`` (and so ``test_step``) returns.
PROBE_OUTPUT_KEYS = ("concept", "variant", "seed", "manipulation_frame",
                     "surprise_consistent", "surprise_inconsistent")
#: Columns of summary.csv, in order (``None`` cells mean "no test", explained in ``note``).
SUMMARY_COLUMNS = ("concept", "variant") + tuple(PairedTestResult.__dataclass_fields__)
#: Histograms hide pairs whose d lies beyond this many SD from the mean (display only).
OUTLIER_SD = 3.0
CONSISTENT_COLOR, INCONSISTENT_COLOR = "tab:blue", "tab:red"


def _numpy(values: Any, dtype: Any) -> np.ndarray:
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu().numpy()
    return np.asarray(values, dtype=dtype)


@dataclass(frozen=True, eq=False)
class PairResults:
    """Per-pair probe results of a run: names, seeds, manipulation frames and per-frame
    surprise [N, T] of both videos. A video's surprise is the sum over its frames (§6)."""

    concept: tuple[str, ...]
    variant: tuple[str, ...]
    seed: np.ndarray
    manipulation_frame: np.ndarray
    surprise_consistent: np.ndarray
    surprise_inconsistent: np.ndarray

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "concept", tuple(str(c) for c in self.concept))
        set_(self, "variant", tuple(str(v) for v in self.variant))
        for name, dtype in (("seed", np.int64), ("manipulation_frame", np.int64),
                            ("surprise_consistent", np.float64),
                            ("surprise_inconsistent", np.float64)):
            set_(self, name, _numpy(getattr(self, name), dtype))
        n = len(self.concept)
        if self.surprise_consistent.ndim != 2 or self.surprise_consistent.shape[0] != n:
            raise ValueError(f"surprise_consistent must be [N={n}, T]; got "
                             f"{self.surprise_consistent.shape}")
        shapes = {"variant": (len(self.variant),), "seed": self.seed.shape,
                  "manipulation_frame": self.manipulation_frame.shape,
                  "surprise_inconsistent": self.surprise_inconsistent.shape}
        expected = {"variant": (n,), "seed": (n,), "manipulation_frame": (n,),
                    "surprise_inconsistent": self.surprise_consistent.shape}
        wrong = {k: v for k, v in shapes.items() if v != expected[k]}
        if wrong:
            raise ValueError(f"per-pair fields disagree with {n} pairs of "
                             f"{self.num_frames} frames: {wrong} (expected {expected})")

    @property
    def num_frames(self) -> int:
        return self.surprise_consistent.shape[1]

    def __len__(self) -> int:
        return len(self.concept)

    @property
    def total_consistent(self) -> np.ndarray:
        """Per-video surprise of the consistent videos: sum over frames, [N]."""
        return self.surprise_consistent.sum(axis=1)

    @property
    def total_inconsistent(self) -> np.ndarray:
        return self.surprise_inconsistent.sum(axis=1)

    @classmethod
    def from_probe_outputs(
        cls,
        outputs: Sequence[Mapping[str, Any]],
        concept_names: Sequence[str] = CONCEPTS,
        variant_names: Sequence[str] = VARIANTS,
    ) -> PairResults:
        """From the dicts ``VOEModel.probe_step`` returns (one per batch), decoding the
        ``concept``/``variant`` indices with the DataModule's name tuples."""
        if not outputs:
            raise ValueError("no probe results: the list of probe_step outputs is empty")
        columns: dict[str, list[np.ndarray]] = {key: [] for key in PROBE_OUTPUT_KEYS}
        for index, output in enumerate(outputs):
            missing = [key for key in PROBE_OUTPUT_KEYS if key not in output]
            if missing:
                raise KeyError(f"probe output {index} lacks {missing}; probe_step must return "
                               f"{list(PROBE_OUTPUT_KEYS)}")
            for key in PROBE_OUTPUT_KEYS:
                columns[key].append(_numpy(output[key], None))
        merged = {key: np.concatenate(values) for key, values in columns.items()}

        def decode(indices: np.ndarray, names: Sequence[str], what: str) -> tuple[str, ...]:
            bad = sorted({int(i) for i in indices if not 0 <= int(i) < len(names)})
            if bad:
                raise ValueError(f"{what} indices {bad} are outside the {len(names)} "
                                 f"{what} names {tuple(names)}")
            return tuple(names[int(i)] for i in indices)

        return cls(
            concept=decode(merged["concept"], concept_names, "concept"),
            variant=decode(merged["variant"], variant_names, "variant"),
            seed=merged["seed"],
            manipulation_frame=merged["manipulation_frame"],
            surprise_consistent=merged["surprise_consistent"],
            surprise_inconsistent=merged["surprise_inconsistent"],
        )

    def select(self, rows: np.ndarray) -> PairResults:
        """The pairs at the given boolean mask or indices."""
        index = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
        return PairResults(
            concept=tuple(self.concept[i] for i in index),
            variant=tuple(self.variant[i] for i in index),
            seed=self.seed[index],
            manipulation_frame=self.manipulation_frame[index],
            surprise_consistent=self.surprise_consistent[index],
            surprise_inconsistent=self.surprise_inconsistent[index],
        )

    def groups(self, pooled: bool = False) -> list[tuple[str, str, PairResults]]:
        """(concept, variant, pairs) per concept/variant: concepts and variants in the order
        of ``specs`` where known, others after them in order of first appearance; with
        ``pooled``, also each concept's ``pooled`` group (standard + counterbalanced)."""
        return [(concept, variant, self.select(rows)) for concept, variant, rows
                in pair_groups(self.concept, self.variant, pooled=pooled)]

    def csv_columns(self) -> list[str]:
        frames = [f"t{t:02d}" for t in range(self.num_frames)]
        return (["concept", "variant", "seed", "manipulation_frame", "surprise_consistent",
                 "surprise_inconsistent", "relative_surprise"]
                + [f"surprise_consistent_{f}" for f in frames]
                + [f"surprise_inconsistent_{f}" for f in frames])

    def to_csv(self, path: str | Path) -> None:
        """pairs.csv: one row per pair; floats written with full precision (repr)."""
        with open(path, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(self.csv_columns())
            totals = zip(self.total_consistent, self.total_inconsistent)
            for i, (con, inc) in enumerate(totals):
                writer.writerow(
                    [self.concept[i], self.variant[i], int(self.seed[i]),
                     int(self.manipulation_frame[i]), repr(float(con)), repr(float(inc)),
                     repr(float(inc - con))]
                    + [repr(float(x)) for x in self.surprise_consistent[i]]
                    + [repr(float(x)) for x in self.surprise_inconsistent[i]])

    @classmethod
    def from_csv(cls, path: str | Path) -> PairResults:
        """Read pairs.csv back (per-frame surprise columns define the results)."""
        with open(path, newline="") as handle:
            rows = list(csv.DictReader(handle))
        if not rows:
            raise ValueError(f"{path} holds no probe pairs")
        columns = list(rows[0])
        con_cols = [c for c in columns if c.startswith("surprise_consistent_t")]
        inc_cols = [c for c in columns if c.startswith("surprise_inconsistent_t")]
        if not con_cols or len(con_cols) != len(inc_cols):
            raise ValueError(f"{path} lacks per-frame surprise columns "
                             "surprise_consistent_tNN / surprise_inconsistent_tNN")
        return cls(
            concept=[r["concept"] for r in rows],
            variant=[r["variant"] for r in rows],
            seed=[int(r["seed"]) for r in rows],
            manipulation_frame=[int(r["manipulation_frame"]) for r in rows],
            surprise_consistent=[[float(r[c]) for c in con_cols] for r in rows],
            surprise_inconsistent=[[float(r[c]) for c in inc_cols] for r in rows],
        )


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


# ----------------------------------------------------------------------------- statistics


def summarize(
    results: PairResults, alpha: float = 0.05, bootstrap: int = 2000, seed: int = 0
) -> list[dict[str, Any]]:
    """One row per concept/variant, and a ``pooled`` row per concept with a counterbalanced
    pair (the test over the union of both variants' pairs): the paired test of summed
    surprise. A group with fewer than two pairs gets ``None`` statistics and a note instead
    of failing the report."""
    rows = []
    for concept, variant, pairs in results.groups(pooled=True):
        row: dict[str, Any] = {"concept": concept, "variant": variant}
        if len(pairs) < 2:
            row.update({key: None for key in SUMMARY_COLUMNS[2:]})
            row.update(n=len(pairs), note=f"only {len(pairs)} pair: no test (needs at least 2)")
        else:
            row.update(paired_test(pairs.total_inconsistent, pairs.total_consistent,
                                   alpha=alpha, bootstrap=bootstrap, seed=seed).as_dict())
        rows.append(row)
    return rows


def _number(value: Any, spec: str = ".3g") -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float):
        if math.isnan(value):
            return "undefined"
        if math.isinf(value):
            return "+inf" if value > 0 else "-inf"
    return format(value, spec)


def format_p(p: float | None) -> str:
    """APA-style p value for a table cell: '< .001', '.034', '1'."""
    if p is None:
        return "n/a"
    if p < 0.001:
        return "< .001"
    return f"{p:.3f}".lstrip("0") if p < 1 else "1"


def _p_phrase(p: float) -> str:
    """'p < .001' or 'p = .034', as in the paper's text."""
    return f"p {format_p(p)}" if p < 0.001 else f"p = {format_p(p)}"


def _interval(value: Any, low: Any, high: Any, spec: str) -> str:
    if value is None:
        return "n/a"
    if low is None or (isinstance(low, float) and math.isnan(low) and not math.isnan(value)):
        return _number(value, spec)
    if low == high == value:
        return _number(value, spec)
    return f"{_number(value, spec)} [{_number(low, spec)}, {_number(high, spec)}]"


def format_verdicts(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """Markdown lines of each concept's VOE verdict (``statistics.concept_verdicts``)."""
    alpha = next((row["alpha"] for row in rows if row.get("alpha") is not None), 0.05)
    lines = []
    for verdict in concept_verdicts(rows, alpha):
        text = "**VOE**" if verdict.voe else verdict.text()
        lines.append(f"- {verdict.concept}: {text} (rule: {verdict.rule})")
    return lines


#: What a frame's surprise is unless told otherwise: the paper's (the VRNN-LRU's).
VRNN_SURPRISE = VOEModel.SURPRISE


def format_markdown(rows: Sequence[Mapping[str, Any]], surprise: str = VRNN_SURPRISE) -> str:
    """The summary as a Markdown table (paper notation), notes as footnotes below it, then
    each concept's VOE verdict; ``surprise`` names what a frame's surprise is."""
    header = ("| concept | variant | n | M [95% CI] | t(df) | p | sig. | d_z [95% CI] "
              "| accuracy | AUROC |")
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    notes = []
    for row in rows:
        marker = ""
        if row.get("note"):
            notes.append(row["note"])
            marker = f" [{len(notes)}]"
        t = "n/a" if row["t"] is None else f"t({row['df']}) = {_number(row['t'], '.2f')}"
        sig = "n/a" if row["significant"] is None else ("yes *" if row["significant"] else "no")
        accuracy = "n/a" if row["accuracy"] is None else f"{100 * row['accuracy']:.1f}%"
        mean = _interval(row["relative_surprise"], row["relative_surprise_ci_low"],
                         row["relative_surprise_ci_high"], ".3g")
        lines.append(
            f"| {row['concept']} | {row['variant']}{marker} | {row['n']} | {mean} "
            f"| {t} | {format_p(row['p_value'])} | {sig} "
            f"| {_interval(row['d_z'], row['d_z_ci_low'], row['d_z_ci_high'], '.2f')} "
            f"| {accuracy} | {_number(row['auroc'], '.3f')} |")
    lines.append("")
    lines.append("M: mean relative surprise d = S(inconsistent) - S(consistent), S = sum over "
                 f"frames of {surprise}; one-tailed paired t-test, H1: M > 0; "
                 "sig.: p < alpha (* as in the paper); accuracy: share of pairs with d > 0; "
                 "pooled: the test over the union of a concept's standard and counterbalanced "
                 "pairs.")
    lines.extend(f"[{i}] {note}" for i, note in enumerate(notes, start=1))
    lines += ["", "Verdicts: a concept shows VOE only when its pooled test is significant and "
              "both variants point the right way (M > 0); without a counterbalanced pair, when "
              "every probe variant is significant. Generalization variants do not enter.", ""]
    lines += format_verdicts(rows)
    return "\n".join(lines) + "\n"


def _json_value(value: Any) -> Any:
    """Strict JSON: non-finite floats become the strings 'inf', '-inf', 'nan' (float() reads
    them back); the row's note says why."""
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


# ----------------------------------------------------------------------------- figures


def panel_grid(count: int, width: float, height: float, max_cols: int = 4):
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
    star = " *" if row["significant"] else ""
    return (f"M = {_number(row['relative_surprise'])}\n"
            f"t({row['df']}) = {_number(row['t'], '.2f')}, {_p_phrase(row['p_value'])}{star}\n"
            f"d_z = {_number(row['d_z'], '.2f')}, acc. = {100 * row['accuracy']:.0f}%")


def histogram_figure(results: PairResults, rows: Sequence[Mapping[str, Any]]) -> Figure:
    """Distribution of d per concept/variant with the test result printed on each panel
    (paper Figure 4); pairs beyond 3 SD of the mean are hidden for display only."""
    groups = results.groups()
    figure, axes = panel_grid(len(groups), 4.2, 3.2)
    by_key = {(row["concept"], row["variant"]): row for row in rows}
    for ax, (concept, variant, pairs) in zip(axes, groups):
        d = pairs.total_inconsistent - pairs.total_consistent
        sd = d.std(ddof=1) if d.size > 1 else 0.0
        shown = d[np.abs(d - d.mean()) <= OUTLIER_SD * sd] if sd > 0 else d
        row = by_key[(concept, variant)]
        color = "tab:green" if row.get("significant") else "tab:gray"
        counts, _, _ = ax.hist(shown, bins=max(5, min(40, int(np.sqrt(shown.size)) * 2)),
                               color=color, alpha=0.75, edgecolor="white")
        ax.set_ylim(0, max(counts.max(), 1) * 1.75)  # headroom for the statistics box
        ax.axvline(0.0, color="black", linewidth=1)
        ax.axvline(d.mean(), color="black", linewidth=1, linestyle="--")
        ax.set_title(f"{concept} / {variant}", fontsize=10)
        ax.set_xlabel("d = S(inconsistent) - S(consistent)")
        ax.set_ylabel("probe pairs")
        hidden = d.size - shown.size
        ax.text(0.98, 0.97, _stats_text(row) + f"\n{hidden} of {d.size} beyond 3 SD hidden",
                transform=ax.transAxes, ha="right", va="top", fontsize=8,
                bbox=dict(boxstyle="round", facecolor="white", alpha=0.85, edgecolor="0.7"))
    title = ("Relative surprise per probe pair (dashed: mean of all pairs). Outliers > 3 SD "
             "removed for display only; tests use all pairs; * p < .05 one-tailed")
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
        aligned[i, start:start + frames] = surprise[i]
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
    aligned at the manipulation frame, with 95% t confidence bands."""
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
            ax.fill_between(offsets, mean - half, mean + half, color=color, alpha=0.2,
                            linewidth=0)
        ax.axvline(0, color="black", linestyle="--", linewidth=1)
        ax.set_title(f"{concept} / {variant} (n = {len(pairs)})", fontsize=10)
        ax.set_xlabel("frame relative to manipulation (dashed)")
        ax.set_ylabel("surprise KL(post || prior)")
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
    figure.get_layout_engine().set(w_pad=0.01, h_pad=0.01, wspace=0.01, hspace=0.01)
    subfigures = np.atleast_1d(figure.subfigures(len(examples), 1))
    for subfigure, example in zip(subfigures, examples):
        frames = _numpy(example.frames, np.uint8)
        expected = np.clip(_numpy(example.expected, np.float32), 0.0, 1.0).transpose(0, 2, 3, 1)
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
            axes[0, column].set_title(f"t={t}", fontsize=8,
                                      color="red" if t == example.manipulation_frame else "black")
        axes[0, 0].set_ylabel("input", fontsize=9)
        axes[1, 0].set_ylabel("expected", fontsize=9)
        title = (f"{example.concept} / {example.variant}, seed {example.seed}: inconsistent "
                 "probe (top) and what the model expected from the frames before (bottom); red: "
                 "manipulation frame")
        subfigure.suptitle(textwrap.fill(title, width=int(14 * figure.get_figwidth())),
                           fontsize=9)
    return figure


def _arrowhead(ax: Any, curve: np.ndarray, color: str) -> None:
    """An arrowhead at the curve's last point, pointing along its last non-zero step."""
    moved = np.flatnonzero(np.any(curve[:-1] != curve[-1], axis=1))
    if moved.size:
        ax.annotate("", xy=curve[-1], xytext=curve[moved[-1]],
                    arrowprops=dict(arrowstyle="-|>", color=color, lw=1.5, mutation_scale=20,
                                    shrinkA=0, shrinkB=0))


#: Panel titles of the t-SNE figure by trajectory kind (others: the kind, capitalised).
TSNE_TITLES = {"prior": "Priors", "memory": "Memory"}
#: Appendix B colours: pair i's consistent and inconsistent curve.
TSNE_CONSISTENT_COLORS = ("cyan", "blue", "teal", "navy")
TSNE_INCONSISTENT_COLORS = ("red", "magenta", "darkred", "purple")


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

    kinds = list(trajectories.get("consistent", {}))
    if not kinds or kinds != list(trajectories.get("inconsistent", {})):
        raise KeyError("trajectories need the same kinds for both videos, e.g. "
                       "dict(consistent=dict(prior, memory), inconsistent=dict(prior, memory)); "
                       f"got {({video: list(v) for video, v in trajectories.items()})}")
    figure = Figure(figsize=(5.5 * len(kinds), 5), layout="constrained")
    axes = np.atleast_1d(figure.subplots(1, len(kinds)))
    for ax, kind in zip(axes, kinds):
        title = TSNE_TITLES.get(kind, kind.capitalize())
        consistent = _numpy(trajectories["consistent"][kind], np.float64)
        inconsistent = _numpy(trajectories["inconsistent"][kind], np.float64)
        n, frames = consistent.shape[:2]
        if inconsistent.shape != consistent.shape:
            raise ValueError(f"{kind}: consistent {consistent.shape} and inconsistent "
                             f"{inconsistent.shape} trajectories disagree")
        points = np.concatenate([consistent, inconsistent]).reshape(2 * n * frames, -1)
        perplexity = min(30.0, (points.shape[0] - 1) / 3.0)
        method = "exact" if points.shape[0] <= 2000 else "barnes_hut"  # exact: faster when small
        embedded = TSNE(n_components=2, perplexity=perplexity, init="pca", method=method,
                        random_state=seed).fit_transform(points).reshape(2, n, frames, 2)
        # Consistent curves wide and pale underneath, so a shared stretch shows both colours.
        for video, palette, name, width, alpha in (
                (0, TSNE_CONSISTENT_COLORS, "consistent", 5.0, 0.45),
                (1, TSNE_INCONSISTENT_COLORS, "inconsistent", 1.6, 1.0)):
            for i in range(n):
                color = palette[i % len(palette)]
                curve = embedded[video, i]
                label = f"{labels[i] if labels else f'pair {i + 1}'} {name}"
                ax.plot(curve[:, 0], curve[:, 1], color=color, linewidth=width, alpha=alpha,
                        label=label, solid_capstyle="round")
                ax.plot(*curve[0], "o", color=color, markersize=6)
                _arrowhead(ax, curve, color)
        ax.set_title(f"{title} (t-SNE; dot = first frame, arrow = last)", fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
    axes[-1].legend(fontsize=8, loc="best")
    figure.suptitle("Object persistence probes: consistent blue/cyan, inconsistent red/magenta",
                    fontsize=10)
    return figure


# ----------------------------------------------------------------------------- writing


def _save(figure: Figure, path: Path) -> Path:
    figure.savefig(path, dpi=110)
    return path


def write_report(
    results: PairResults,
    out_dir: str | Path,
    predictions: Sequence[PredictionExample] | None = None,
    trajectories: Mapping[str, Any] | None = None,
    *,
    trajectory_labels: Sequence[str] | None = None,
    cue_audit: cues.CueAudit | None = None,
    alpha: float = 0.05,
    bootstrap: int = 2000,
    seed: int = 0,
    echo: bool = True,
    surprise: str = VRNN_SURPRISE,
) -> list[dict[str, Any]]:
    """Write ``out_dir/voe_report/`` (module docstring) and return the summary rows.
    ``predictions`` give predictions_<concept>.png, ``trajectories`` (see ``tsne_figure``)
    give tsne_object_persistence.png, ``cue_audit`` (scores of the same pairs) gives
    cues.md/csv/json; ``echo`` prints the Markdown tables; ``surprise`` names what a frame's
    surprise is (the model's ``SURPRISE``)."""
    if len(results) == 0:
        raise ValueError("no probe results to report")
    report_dir = Path(out_dir) / "voe_report"
    report_dir.mkdir(parents=True, exist_ok=True)
    rows = summarize(results, alpha=alpha, bootstrap=bootstrap, seed=seed)

    document = {"alpha": alpha, "bootstrap_resamples": bootstrap, "num_pairs": len(results),
                "num_frames": results.num_frames,
                "video_surprise": f"sum over frames of {surprise}",
                "rows": [{k: _json_value(v) for k, v in row.items()} for row in rows],
                "verdicts": [{"concept": v.concept, "voe": v.voe, "verdict": v.text(),
                              "rule": v.rule} for v in concept_verdicts(rows, alpha)]}
    (report_dir / "summary.json").write_text(json.dumps(document, indent=2) + "\n")
    with open(report_dir / "summary.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=SUMMARY_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    markdown = format_markdown(rows, surprise)
    (report_dir / "summary.md").write_text(markdown)
    results.to_csv(report_dir / "pairs.csv")
    if cue_audit is not None:
        if len(cue_audit) != len(results):
            raise ValueError(f"the cue audit scored {len(cue_audit)} pairs, the model "
                             f"{len(results)}: they must be the same pairs")
        cue_rows = cue_audit.rows(alpha=alpha)
        title = "Cue audit on the model's test pairs"
        cues.write_audit(cue_rows, report_dir, model_rows=rows, title=title, alpha=alpha,
                         num_pairs=len(cue_audit))
        markdown += "\n" + cues.format_markdown(cue_rows, rows, title)

    _save(histogram_figure(results, rows), report_dir / "histograms.png")
    _save(per_frame_figure(results), report_dir / "surprise_per_frame.png")
    by_concept: dict[str, list[PredictionExample]] = {}
    for example in predictions or ():
        by_concept.setdefault(example.concept, []).append(example)
    for concept, examples in by_concept.items():
        _save(predictions_figure(examples), report_dir / f"predictions_{concept}.png")
    if trajectories is not None:
        _save(tsne_figure(trajectories, trajectory_labels, seed=seed),
              report_dir / "tsne_object_persistence.png")
    if echo:
        _print_markdown(markdown, report_dir)
    return rows


def _print_markdown(markdown: str, report_dir: Path) -> None:
    from rich.console import Console
    from rich.markdown import Markdown

    console = Console()
    if console.is_terminal:
        console.print(Markdown(markdown))
    else:
        print(markdown, end="")
    print(f"VOE report written to {report_dir}")


# ----------------------------------------------------------------------------- callback


def _stacked(videos: list[dict[str, torch.Tensor]], device: torch.device
             ) -> dict[str, torch.Tensor]:
    """Kept videos (frames and, where the batch had them, mask and camera) as one batch."""
    return {key: torch.stack([video[key] for video in videos]).to(device) for key in videos[0]}


def _gather(value: Any) -> list[Any]:
    """All ranks' values under torch.distributed (DDP test), else [value]."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1:
        gathered: list[Any] = [None] * dist.get_world_size()
        dist.all_gather_object(gathered, value)
        return gathered
    return [value]


class VOEReportCallback(Callback):
    """Collects ``test_step`` outputs (the ``probe_step`` dict) and, at the end of ``test``,
    writes the VOE report into ``out_dir`` or the run directory (``trainer.log_dir``). Keeps
    up to ``max_prediction_examples`` inconsistent probes per concept/variant for
    predictions_<concept>.png (``pl_module.expected_frames``) and ``tsne_pairs``
    object-persistence pairs, standard and counterbalanced alternately, for the t-SNE figure
    (``pl_module.trajectories``). With ``cue_audit`` it scores the physics-blind cues of every
    test batch's pairs (``voe_lightning.cues``, on the batch's device), so the cue rows of
    cues.md/cues.csv share the model's pairs and n. Names are decoded with
    ``trainer.datamodule.concept_names`` / ``variant_names``. After the test, ``summary``
    holds the rows and ``report_dir`` the directory written."""

    def __init__(
        self,
        out_dir: str | None = None,
        max_prediction_examples: int = 1,
        tsne_pairs: int = 2,
        alpha: float = 0.05,
        bootstrap: int = 2000,
        seed: int = 0,
        cue_audit: bool = True,
    ) -> None:
        if max_prediction_examples < 0 or tsne_pairs < 0:
            raise ValueError("max_prediction_examples and tsne_pairs must be >= 0, got "
                             f"{max_prediction_examples} and {tsne_pairs}")
        self.out_dir = out_dir
        self.max_prediction_examples = max_prediction_examples
        self.tsne_pairs = tsne_pairs
        self.alpha, self.bootstrap, self.seed = alpha, bootstrap, seed
        self.cue_audit = cue_audit
        self.summary: list[dict[str, Any]] | None = None
        self.report_dir: Path | None = None
        self._failed = self._ended = False
        self._reset()

    def _reset(self) -> None:
        self._outputs: list[dict[str, np.ndarray]] = []
        self._cues: list[cues.CueAudit] = []
        self._examples: dict[tuple[int, int], list[dict[str, Any]]] = {}
        self._tsne: dict[int, list[dict[str, Any]]] = {}

    @staticmethod
    def _names(trainer: Trainer) -> tuple[tuple[str, ...], tuple[str, ...]]:
        datamodule = getattr(trainer, "datamodule", None)
        missing = [name for name in ("concept_names", "variant_names")
                   if not hasattr(datamodule, name)]
        if missing:
            raise AttributeError(
                f"VOEReportCallback decodes probe indices with trainer.datamodule."
                f"{' and .'.join(missing)}, which {type(datamodule).__name__} lacks; test with "
                "a probe DataModule (e.g. the joint or per-concept DataModule)")
        return tuple(datamodule.concept_names), tuple(datamodule.variant_names)

    def setup(self, trainer: Trainer, pl_module: LightningModule, stage: str) -> None:
        if not isinstance(pl_module, SurpriseModel):
            raise TypeError(f"VOEReportCallback needs a SurpriseModel (surprise, expected_frames "
                            f"and trajectories, voe_lightning.model.base); got "
                            f"{type(pl_module).__name__}")
        self.summary, self.report_dir, self._failed, self._ended = None, None, False, False

    def on_exception(self, trainer: Trainer, pl_module: LightningModule, exception: BaseException
                     ) -> None:
        self._failed = True

    def teardown(self, trainer: Trainer, pl_module: LightningModule, stage: str) -> None:
        # Lightning skips the whole test loop (and on_test_end) when the loaders are empty.
        if stage == "test" and not self._ended and not self._failed:
            self._no_results()

    @staticmethod
    def _no_results() -> None:
        raise RuntimeError(
            "VOEReportCallback collected no probe results: the test dataloaders yielded no "
            "probe pairs (does the DataModule have test probes for its concepts?)")

    def on_test_start(self, trainer: Trainer, pl_module: LightningModule) -> None:
        self._reset()
        self._concept_names, self._variant_names = self._names(trainer)

    def on_test_batch_end(self, trainer: Trainer, pl_module: LightningModule, outputs: Any,
                          batch: Any, batch_idx: int, dataloader_idx: int = 0) -> None:
        if not isinstance(outputs, Mapping):
            raise TypeError(f"VOEReportCallback needs test_step to return the probe_step dict "
                            f"with {list(PROBE_OUTPUT_KEYS)}; got {type(outputs).__name__}")
        missing = [key for key in PROBE_OUTPUT_KEYS if key not in outputs]
        if missing:
            raise KeyError(f"test_step output lacks {missing} (needs {list(PROBE_OUTPUT_KEYS)})")
        stored = {key: _numpy(outputs[key], None) for key in PROBE_OUTPUT_KEYS}
        self._outputs.append(stored)
        if self.cue_audit:
            self._cues.append(cues.CueAudit.score_batch(batch, self._concept_names,
                                                        self._variant_names))
        self._keep_examples(stored, batch)

    def _keep_examples(self, stored: Mapping[str, np.ndarray], batch: Any) -> None:
        persistence = (self._concept_names.index("object_persistence")
                       if "object_persistence" in self._concept_names else None)
        for i, (concept, variant) in enumerate(zip(stored["concept"], stored["variant"])):
            concept, variant = int(concept), int(variant)
            meta = {"concept": concept, "variant": variant, "seed": int(stored["seed"][i]),
                    "manipulation_frame": int(stored["manipulation_frame"][i])}
            kept = self._examples.setdefault((concept, variant), [])
            videos = {side: {"frames": batch[side, "frames"][i].cpu().clone()}
                      | {name: value[i].cpu().clone()
                         for name, value in video_inputs(batch, side).items()}
                      for side in ("consistent", "inconsistent")}
            if len(kept) < self.max_prediction_examples:
                kept.append(meta | {"inconsistent": videos["inconsistent"]})
            tsne = self._tsne.setdefault(variant, []) if concept == persistence else None
            if tsne is not None and len(tsne) < self.tsne_pairs:
                tsne.append(meta | videos)

    def on_test_end(self, trainer: Trainer, pl_module: LightningModule) -> None:
        gathered = _gather((self._outputs, self._examples, self._tsne, self._cues))
        self._ended = True  # on every rank; only rank zero writes the report
        # trainer.log_dir broadcasts under DDP: every rank must ask for it.
        out_dir = self.out_dir or trainer.log_dir or trainer.default_root_dir
        if not trainer.is_global_zero:
            return
        outputs = [output for rank in gathered for output in rank[0]]
        if not outputs:
            self._no_results()
        results = PairResults.from_probe_outputs(outputs, self._concept_names,
                                                 self._variant_names)
        examples = [e for rank in gathered for kept in rank[1].values() for e in kept]
        tsne = [e for rank in gathered for kept in rank[2].values() for e in kept]
        cue_audit = (cues.CueAudit.concatenate(a for rank in gathered for a in rank[3])
                     if self.cue_audit else None)
        was_training = pl_module.training
        pl_module.eval()
        try:
            with torch.no_grad():
                predictions = self._predictions(pl_module, examples)
                trajectories, labels = self._trajectories(pl_module, tsne)
        finally:
            pl_module.train(was_training)
        self.summary = write_report(results, out_dir, predictions, trajectories,
                                    trajectory_labels=labels, cue_audit=cue_audit,
                                    alpha=self.alpha, bootstrap=self.bootstrap,
                                    seed=self.seed, surprise=pl_module.SURPRISE)
        self.report_dir = Path(out_dir) / "voe_report"
        self._write_benchmark_metrics(trainer.datamodule, outputs)

    def _write_benchmark_metrics(self, datamodule: Any, outputs: list[dict[str, Any]]) -> None:
        """External benchmarks (IntPhys, Physical Concepts) add their own published metrics."""
        if not hasattr(datamodule, "benchmark_metrics"):
            return
        merged = {key: np.concatenate([output[key] for output in outputs])
                  for key in PROBE_OUTPUT_KEYS}
        metrics = datamodule.benchmark_metrics(merged, alpha=self.alpha, bootstrap=self.bootstrap)
        path = self.report_dir / "benchmark_metrics.json"
        path.write_text(json.dumps(metrics, indent=2, default=lambda v: v.item()) + "\n")
        print(f"benchmark metrics written to {path}")

    def _predictions(self, pl_module: LightningModule,
                     examples: list[dict[str, Any]]) -> list[PredictionExample]:
        if not examples:
            return []
        video = _stacked([e["inconsistent"] for e in examples], pl_module.device)
        expected = pl_module.expected_frames(**video).float().cpu().numpy()
        return [PredictionExample(
            concept=self._concept_names[e["concept"]], variant=self._variant_names[e["variant"]],
            seed=e["seed"], manipulation_frame=e["manipulation_frame"],
            frames=e["inconsistent"]["frames"].numpy(), expected=expected[i])
            for i, e in enumerate(examples)]

    def _trajectories(self, pl_module: LightningModule, tsne: list[dict[str, Any]]):
        # Interleave variants (standard, counterbalanced, standard, ...) up to tsne_pairs.
        by_variant: dict[int, list[dict[str, Any]]] = {}
        for e in tsne:
            by_variant.setdefault(e["variant"], []).append(e)
        order = sorted(by_variant, key=lambda v: self._variant_names[v] != "standard")
        chosen = [by_variant[v][i] for i in range(self.tsne_pairs) for v in order
                  if i < len(by_variant[v])][: self.tsne_pairs]
        if len(chosen) < 2:
            if self.tsne_pairs:
                rank_zero_warn("fewer than 2 object-persistence probe pairs in the test set; "
                               "tsne_object_persistence.png not written")
            return None, None
        trajectories = {}
        for video in ("consistent", "inconsistent"):
            courses = pl_module.trajectories(**_stacked([e[video] for e in chosen],
                                                        pl_module.device))
            trajectories[video] = {k: v.float().cpu().numpy() for k, v in courses.items()}
        labels = [f"{self._variant_names[e['variant']]} (seed {e['seed']})" for e in chosen]
        return trajectories, labels
