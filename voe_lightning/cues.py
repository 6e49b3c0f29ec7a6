"""The cue audit (docs/architecture.md §4, §8): physics-blind scores of each probe video, tested
with the same paired statistics as a model's surprise. A score that tells inconsistent from
consistent videos of a concept's pooled pairs is a low-level cue in the stimuli, not evidence of
physics, so these rows stand beside every model result (``test`` writes them to
``voe_report/cues.*``) and ``python -m voe_lightning audit --root DIR`` runs them on any probe split
of a store.

Every score is computed on the frames after ``manipulation_frame`` (the two videos of a pair are
identical up to and including it), per video, with frames x_t in [0, 1]:

- ``foreground_pixels``: visible object pixels (mask id > 0), summed over frames;
- ``motion_energy``: mean absolute difference of consecutive frames, summed;
- ``copy_last_error``: mean squared error of predicting each frame by the one before;
- ``linear_extrapolation_error``: mean squared error of predicting x_t by
  clip(2 x_{t-1} - x_{t-2}, 0, 1);
- ``pixel_novelty``: per pixel, the L1 distance of its colour to the nearest colour seen at that
  place in any earlier frame, summed (something new appearing where it never was).

A pair whose masks are all zero in both videos (benchmarks without masks, e.g. IntPhys) has no
``foreground_pixels`` score; its rows say so instead of testing zeros.

``accuracy`` here counts a tied pair as half (scores that cannot differ, such as visible pixels
under a pure colour change, sit at 0.5 = chance rather than 0); ``p_two_sided`` flags a cue
that separates the pairs in either direction."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from scipy import stats

from voe_lightning import specs, statistics
from voe_lightning.statistics_format import BRIEF, format_alpha, json_row, row_text, rows_alpha
from voe_lightning.verdicts import pair_groups

__all__ = [
    "CUES",
    "CUE_COLUMNS",
    "CueAudit",
    "FRAME_LOCAL_CUES",
    "audit",
    "audit_records",
    "audit_split",
    "cue_table",
    "format_correlations",
    "format_markdown",
    "frame_scores",
    "score_videos",
    "tracked_cues",
    "write_audit",
]

#: The physics-blind scorers, in table order; ``MASK_CUES`` need object masks.
CUES: tuple[str, ...] = ("foreground_pixels", "motion_energy", "copy_last_error",
                         "linear_extrapolation_error", "pixel_novelty")
MASK_CUES: tuple[str, ...] = ("foreground_pixels",)
#: The cues that read each frame on its own; the fairness gate holds them at chance on every
#: pooled row (pixel novelty needs a memory of the video).
FRAME_LOCAL_CUES: tuple[str, ...] = CUES[:4]
#: Short column titles of the compact tables.
CUE_TITLES = {"foreground_pixels": "foreground", "motion_energy": "motion",
              "copy_last_error": "copy-last", "linear_extrapolation_error": "lin. extrap.",
              "pixel_novelty": "novelty"}
SIDES = ("consistent", "inconsistent")
#: Columns of cues.csv, in order (``None`` cells mean "no test", explained in ``note``).
CUE_COLUMNS = (("concept", "variant", "cue")
               + tuple(f for f in statistics.PairedTestResult.__dataclass_fields__ if f != "note")
               + ("p_two_sided", "note"))
#: How a compact table's cell writes accuracy and d_z: '61% / +0.52'.
CELL_STYLE = replace(BRIEF, d_z="+.2f")
#: Columns of cue_correlations.csv (``CueAudit.model_correlations``).
CORRELATION_COLUMNS = ("concept", "variant", "cue", "n", "r", "p_two_sided", "alpha", "note")


def frame_scores(
    frames: torch.Tensor, mask: torch.Tensor | None, first: int = 1
) -> dict[str, torch.Tensor]:
    """Every cue's per-frame value of a batch of videos: uint8 frames [B, T, H, W, 3], mask
    [B, T, H, W] (or None: ``foreground_pixels`` is NaN); float64 [B, T] per cue. Frame t's
    value reads frames up to t only (0 where a cue needs earlier frames); ``pixel_novelty`` is
    computed from frame ``first`` on (0 before), as the frames before it are not scored."""
    if frames.ndim != 5 or frames.shape[-1] != 3:
        raise ValueError(f"frames must be [B, T, H, W, 3], got {tuple(frames.shape)}")
    batch, num_frames = frames.shape[:2]
    x = specs.to_model_input(frames).contiguous()  # [B, T, 3, H, W]: ~10x faster than NHWC

    def per_frame(values: torch.Tensor) -> torch.Tensor:
        """Values of the last frames [B, T - k] as [B, T], 0 for the first k frames."""
        padded = torch.zeros(batch, num_frames, dtype=torch.float64, device=frames.device)
        padded[:, num_frames - values.shape[1]:] = values.double()
        return padded

    difference = x[:, 1:] - x[:, :-1]
    predicted = (2.0 * x[:, 1:-1] - x[:, :-2]).clamp_(0.0, 1.0)
    novelty = torch.zeros(batch, num_frames, dtype=torch.float64, device=frames.device)
    for t in range(max(first, 1), num_frames):
        nearest = (x[:, 0] - x[:, t]).abs_().sum(dim=1)  # [B, H, W], L1 over channels
        for s in range(1, t):
            nearest = torch.minimum(nearest, (x[:, s] - x[:, t]).abs_().sum(dim=1))
        novelty[:, t] = nearest.sum(dim=(1, 2)).double()
    scores = {
        "motion_energy": per_frame(difference.abs().mean(dim=(2, 3, 4))),
        "copy_last_error": per_frame(difference.square().mean(dim=(2, 3, 4))),
        "linear_extrapolation_error": per_frame((x[:, 2:] - predicted).square().mean(dim=(2, 3, 4))),
        "pixel_novelty": novelty,
        "foreground_pixels": (
            torch.full((batch, num_frames), math.nan, dtype=torch.float64, device=frames.device)
            if mask is None else (mask > 0).sum(dim=(2, 3)).double()),
    }
    return {cue: scores[cue] for cue in CUES}


def score_videos(
    frames: torch.Tensor, mask: torch.Tensor | None, manipulation_frame: torch.Tensor
) -> dict[str, torch.Tensor]:
    """Every cue's score of a batch of videos: uint8 frames [B, T, H, W, 3], mask [B, T, H, W]
    (or None: no ``foreground_pixels``, NaN), manipulation frame [B]; float64 [B] per cue.
    Runs on the frames' device; each score sums the per-frame values (``frame_scores``) over
    the frames t > m."""
    if frames.ndim != 5 or frames.shape[-1] != 3:
        raise ValueError(f"frames must be [B, T, H, W, 3], got {tuple(frames.shape)}")
    batch, num_frames = frames.shape[:2]
    m = torch.as_tensor(manipulation_frame, device=frames.device).reshape(-1).long()
    if m.numel() != batch or bool(((m < 0) | (m >= num_frames)).any()):
        raise ValueError(f"manipulation_frame must hold {batch} values in [0, {num_frames - 1}], "
                         f"got {m.tolist()}")
    after = (torch.arange(num_frames, device=frames.device)[None] > m[:, None]).double()
    per_frame = frame_scores(frames, mask, first=int(m.min()) + 1)
    return {cue: (values * after).sum(dim=1) for cue, values in per_frame.items()}


def _mask(video: Any) -> torch.Tensor | None:
    return video["mask"] if "mask" in video.keys() else None


@dataclass(frozen=True, eq=False)
class CueAudit:
    """Per-pair cue scores of probe pairs: ``scores[side][cue]`` float64 arrays over pairs
    (side is ``consistent`` or ``inconsistent``; NaN where a cue cannot be scored), with each
    pair's concept and variant name."""

    concepts: np.ndarray
    variants: np.ndarray
    scores: dict[str, dict[str, np.ndarray]]

    def __len__(self) -> int:
        return len(self.concepts)

    @classmethod
    def score_batch(
        cls,
        batch: Any,
        concept_names: Sequence[str] = specs.CONCEPTS,
        variant_names: Sequence[str] = specs.VARIANTS,
    ) -> CueAudit:
        """Score a batch of probe pairs (a stacked probe TensorDict, as loaders yield them);
        ``concept``/``variant`` indices decode with the given name tuples. A pair whose masks
        are all zero in both videos gets NaN ``foreground_pixels`` (no masks to count)."""
        m = batch["manipulation_frame"]
        scores = {side: score_videos(batch[side]["frames"], _mask(batch[side]), m)
                  for side in SIDES}
        masks = [_mask(batch[side]) for side in SIDES]
        if all(mask is not None for mask in masks):
            unmasked = ~torch.stack([(mask != 0).flatten(1).any(dim=1) for mask in masks]).any(dim=0)
            for side in SIDES:
                for cue in MASK_CUES:
                    scores[side][cue][unmasked] = math.nan
        return cls(
            np.array([concept_names[int(i)] for i in batch["concept"].reshape(-1)], dtype=object),
            np.array([variant_names[int(i)] for i in batch["variant"].reshape(-1)], dtype=object),
            {side: {cue: values.cpu().numpy() for cue, values in by_cue.items()}
             for side, by_cue in scores.items()},
        )

    @classmethod
    def concatenate(cls, audits: Iterable[CueAudit]) -> CueAudit:
        """One audit of all the pairs of ``audits``, in order."""
        audits = list(audits)
        if not audits:
            raise ValueError("no cue scores to concatenate (no probe pairs were scored)")
        return cls(
            np.concatenate([a.concepts for a in audits]),
            np.concatenate([a.variants for a in audits]),
            {side: {cue: np.concatenate([a.scores[side][cue] for a in audits]) for cue in CUES}
             for side in SIDES},
        )

    def groups(self) -> list[tuple[str, str, np.ndarray]]:
        """(concept, variant, row selector) for every variant, and a ``pooled`` group for each
        concept with a counterbalanced pair (``verdicts.pair_groups``)."""
        return pair_groups(self.concepts, self.variants)

    def rows(self, alpha: float = statistics.ALPHA, bootstrap: int = 0) -> list[dict[str, Any]]:
        """One row per (concept, variant or pooled, cue), columns ``CUE_COLUMNS``: the test
        of score(inconsistent) - score(consistent) the model's rows get
        (``statistics.group_test``: stratified for pooled), ``accuracy`` counting ties as half."""
        rows = []
        for concept, variant, selected in self.groups():
            for cue in CUES:
                inconsistent = self.scores["inconsistent"][cue][selected]
                consistent = self.scores["consistent"][cue][selected]
                row: dict[str, Any] = dict.fromkeys(CUE_COLUMNS)
                row.update(concept=concept, variant=variant, cue=cue, n=int(selected.sum()))
                unscored = int(np.isnan(inconsistent).sum() + np.isnan(consistent).sum())
                untested = statistics.untested_reason(variant, self.variants[selected])
                if unscored:
                    row["note"] = (f"{cue} skipped: {unscored} of {2 * row['n']} videos have no "
                                   "object mask (all zero or absent)")
                elif untested:
                    row["note"] = untested
                else:
                    result = statistics.group_test(variant, inconsistent, consistent,
                                                   self.variants[selected], alpha=alpha,
                                                   bootstrap=bootstrap)
                    row.update(result.as_dict())
                    d = inconsistent - consistent
                    row["accuracy"] = float(np.mean(d > 0) + 0.5 * np.mean(d == 0))
                    row["p_two_sided"] = _two_sided(result.t, result.df)
                rows.append(row)
        return rows

    def model_correlations(self, model_difference: np.ndarray,
                           alpha: float = statistics.ALPHA) -> list[dict[str, Any]]:
        """How closely a model tracks each cue pair by pair: per group (``groups``) and cue,
        Pearson's r across pairs between the model's relative surprise d (``model_difference``,
        one per pair, in this audit's order) and the cue's d, with its two-sided p
        (``scipy.stats.pearsonr``). A model that follows a cue has r far from 0 even in a
        pooled group where its accuracy is at chance; columns ``CORRELATION_COLUMNS``."""
        model_difference = np.asarray(model_difference, dtype=np.float64)
        if model_difference.shape != (len(self),):
            raise ValueError(f"model_difference must hold one value per scored pair ({len(self)}), "
                             f"got shape {model_difference.shape}")
        differences = {cue: self.scores["inconsistent"][cue] - self.scores["consistent"][cue]
                       for cue in CUES}
        rows = []
        for concept, variant, selected in self.groups():
            model = model_difference[selected]
            for cue in CUES:
                cue_d = differences[cue][selected]
                row = dict.fromkeys(CORRELATION_COLUMNS)
                row.update(concept=concept, variant=variant, cue=cue, n=int(selected.sum()),
                           alpha=alpha)
                if np.isnan(cue_d).any() or np.isnan(model).any():
                    row["note"] = f"{cue} or the model's surprise is not scored for every pair"
                elif row["n"] < 3:
                    row["note"] = f"only {row['n']} pairs: no correlation (needs at least 3)"
                elif np.ptp(cue_d) == 0 or np.ptp(model) == 0:
                    row["note"] = "constant across pairs: r undefined"
                else:
                    result = stats.pearsonr(model, cue_d)
                    row.update(r=float(result.statistic), p_two_sided=float(result.pvalue))
                rows.append(row)
        return rows


def tracked_cues(
    correlation_rows: Iterable[Mapping[str, Any]],
) -> dict[tuple[str, str], Mapping[str, Any]]:
    """Per (concept, variant) of ``CueAudit.model_correlations`` rows: the row of the
    frame-local cue whose r is largest in size (rows without an r are skipped)."""
    tracked: dict[tuple[str, str], Mapping[str, Any]] = {}
    for row in correlation_rows:
        key = (row["concept"], row["variant"])
        if row["cue"] in FRAME_LOCAL_CUES and row["r"] is not None and (
                key not in tracked or abs(row["r"]) > abs(tracked[key]["r"])):
            tracked[key] = row
    return tracked


def _two_sided(t: float, df: float) -> float:
    """Two-sided p of a paired t statistic (inf: 0; undefined, every d = 0: 1)."""
    if math.isnan(t):
        return 1.0
    return 0.0 if math.isinf(t) else float(2.0 * stats.t.sf(abs(t), df))


def _batches(records: Iterable[Any], batch_size: int) -> Iterable[Any]:
    chunk = []
    for record in records:
        chunk.append(record)
        if len(chunk) == batch_size:
            yield torch.stack(chunk)
            chunk = []
    if chunk:
        yield torch.stack(chunk)


def audit_records(
    records: Iterable[Any], batch_size: int = 64, progress: bool = False, total: int | None = None
) -> CueAudit:
    """Score probe pairs: unbatched probe records as in ``specs.probe_spec`` (stacked
    ``batch_size`` at a time) or, when ``batch_size`` is 0, batches a loader already made."""
    if batch_size < 0:
        raise ValueError(f"batch_size must be >= 0 (0: records are batches already), got {batch_size}")
    batches = records if batch_size == 0 else _batches(records, batch_size)
    if progress:
        from tqdm.auto import tqdm

        batches = tqdm(batches, desc="cue audit", unit="batch", total=total)
    return CueAudit.concatenate(CueAudit.score_batch(batch) for batch in batches)


def audit_split(
    root: str | Path,
    split: str = "test",
    concepts: Sequence[str] | None = None,
    batch_size: int = 64,
    num_workers: int = 0,
    progress: bool = False,
) -> CueAudit:
    """Score every probe pair of ``split`` (val, test or generalization) of the store at
    ``root`` for ``concepts`` (default: every concept the store holds)."""
    from torch.utils.data import ConcatDataset

    from voe_lightning import store

    if store.SPLIT_RECORD_TYPE.get(split) != "probe":
        probe_splits = [s for s, kind in store.SPLIT_RECORD_TYPE.items() if kind == "probe"]
        raise ValueError(f"split {split!r} holds no probe pairs; probe splits are: "
                         f"{', '.join(probe_splits)}")
    manifest = store.read_manifest(root)
    if manifest is None:
        raise FileNotFoundError(f"no dataset at {root} (create one with `python -m voe_lightning "
                                f"generate --root {root}`)")
    concepts = list(dict.fromkeys(concepts or manifest["concepts"]))
    parts = [store.open_split(root, concept, split) for concept in concepts]
    dataset = ConcatDataset([part for part in parts if len(part)])
    if not len(dataset):
        raise ValueError(f"the {split} split of {root} holds no probe pairs for "
                         f"{', '.join(concepts)}")
    loader = store.record_loader(dataset, batch_size, num_workers)
    return audit_records(loader, batch_size=0, progress=progress, total=len(loader))


# ----------------------------------------------------------------------------- tables and files


def _cell(row: Mapping[str, Any] | None) -> tuple[str, bool]:
    """'acc% / d_z' of a row, and whether it separates the pairs (p_two_sided or p < alpha)."""
    if row is None or row.get("accuracy") is None:
        return "n/a", False
    text = row_text(row, CELL_STYLE)
    separates = row["p_two_sided"] < row["alpha"] if "p_two_sided" in row else row["significant"]
    return f"{text.accuracy} / {text.d_z}", bool(separates)


def _table_cells(
    cue_rows: Sequence[Mapping[str, Any]], model_rows: Sequence[Mapping[str, Any]] | None
) -> list[tuple[str, str, int, list[tuple[str, bool]]]]:
    """(concept, variant, n, cells) per group: the model's cell first when given, then one
    cell per cue."""
    by_key = {(r["concept"], r["variant"], r["cue"]): r for r in cue_rows}
    models = {(r["concept"], r["variant"]): r for r in model_rows or ()}
    table = []
    for concept, variant in dict.fromkeys((r["concept"], r["variant"]) for r in cue_rows):
        cells = [_cell(models.get((concept, variant)))] if model_rows is not None else []
        cells += [_cell(by_key.get((concept, variant, cue))) for cue in CUES]
        n = by_key[(concept, variant, CUES[0])]["n"]
        table.append((concept, variant, n, cells))
    return table


def format_markdown(
    cue_rows: Sequence[Mapping[str, Any]],
    model_rows: Sequence[Mapping[str, Any]] | None = None,
    title: str = "Cue audit",
) -> str:
    """The compact cue table as Markdown: per concept/variant (and pooled), accuracy / d_z of
    each cue, beside the model's when ``model_rows`` (report summary rows) are given. Cue
    cells that separate the pairs (two-sided p < alpha) are bold; model cells with one-tailed
    p < alpha carry *. Notes (skipped cues, degenerate tests) follow the table."""
    model = model_rows is not None
    header = (["concept", "variant", "n"] + (["model (surprise)"] if model else [])
              + [CUE_TITLES[cue] for cue in CUES])
    alpha = rows_alpha(cue_rows)
    lines = [f"## {title} ({format_alpha(alpha)})", "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for concept, variant, n, cells in _table_cells(cue_rows, model_rows):
        texts = []
        for index, (text, separates) in enumerate(cells):
            if model and index == 0:
                texts.append(text + (" *" if separates else ""))
            else:
                texts.append(f"**{text}**" if separates else text)
        name = f"**{variant}**" if variant == statistics.POOLED else variant
        lines.append(f"| {concept} | {name} | {n} | " + " | ".join(texts) + " |")
    lines += ["", "Each cell: accuracy / d_z of d = score(inconsistent) - score(consistent) on "
              "the same pairs (cue accuracy counts ties as half: 50% is chance). Cues are "
              "physics-blind: " + ", ".join(f"{CUE_TITLES[c]} = {c}" for c in CUES) + ". "
              f"**Bold**: the cue separates the pairs (two-sided p < {alpha:g}), so a model "
              "could do as well without physics."
              + (f" Model: accuracy / d_z of surprise, * one-tailed p < {alpha:g}; pooled rows "
                 "(cues' too) are the stratified test of the two variants." if model else
                 " Pooled rows are the stratified test of the two variants.")
              + " Full statistics in cues.csv."]
    notes = [f"{r['concept']}/{r['variant']}, {CUE_TITLES[r['cue']]}: {r['note']}"
             for r in cue_rows if r.get("note") and "bootstrap" not in r["note"]]
    lines += [f"- {note}" for note in notes]
    return "\n".join(lines) + "\n"


def format_correlations(correlation_rows: Sequence[Mapping[str, Any]],
                        title: str = "Does the model's surprise track a cue, pair by pair?") -> str:
    """Markdown table of ``CueAudit.model_correlations``: r per concept/variant (and pooled)
    and cue, bold where two-sided p < alpha."""
    by_key = {(r["concept"], r["variant"], r["cue"]): r for r in correlation_rows}
    header = ["concept", "variant", "n"] + [CUE_TITLES[cue] for cue in CUES]
    alpha = rows_alpha(correlation_rows)
    lines = [f"## {title} ({format_alpha(alpha)})", "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for concept, variant in dict.fromkeys((r["concept"], r["variant"]) for r in correlation_rows):
        cells = []
        for cue in CUES:
            row = by_key[(concept, variant, cue)]
            if row["r"] is None:
                cells.append("n/a")
            else:
                text = f"{row['r']:+.2f}"
                cells.append(f"**{text}**" if row["p_two_sided"] < row["alpha"] else text)
        name = f"**{variant}**" if variant == statistics.POOLED else variant
        n = by_key[(concept, variant, CUES[0])]["n"]
        lines.append(f"| {concept} | {name} | {n} | " + " | ".join(cells) + " |")
    lines += ["", "Each cell: Pearson's r across pairs between the model's relative surprise "
              "S(inconsistent) - S(consistent) and the cue's score(inconsistent) - "
              f"score(consistent); **bold**: two-sided p < {alpha:g}. A model whose pooled "
              "accuracy is at chance but whose r with a cue is large follows that cue in each "
              "variant, and the variants cancel; physics would not depend on the cue. Full "
              "values in cue_correlations.csv."]
    return "\n".join(lines) + "\n"


def cue_table(
    cue_rows: Sequence[Mapping[str, Any]],
    model_rows: Sequence[Mapping[str, Any]] | None = None,
    title: str = "Cue audit",
):
    """The compact cue table as a rich Table (separating cue cells red, pooled rows bold)."""
    from rich.table import Table

    alpha = rows_alpha(cue_rows)
    table = Table(title=f"{title} ({format_alpha(alpha)})",
                  caption="accuracy (ties half) / d_z; red: the cue separates the pairs "
                  f"(two-sided p < {alpha:g})")
    for column in ["concept", "variant", "n"] + (["model"] if model_rows is not None else []) + [
            CUE_TITLES[cue] for cue in CUES]:
        table.add_column(column, justify="left" if column in ("concept", "variant") else "right")
    groups = _table_cells(cue_rows, model_rows)
    for index, (concept, variant, n, cells) in enumerate(groups):
        styled = []
        for column, (text, separates) in enumerate(cells):
            is_model = model_rows is not None and column == 0
            styled.append(text + " *" if is_model and separates
                          else f"[red]{text}[/red]" if separates else text)
        last = index + 1 == len(groups) or groups[index + 1][0] != concept
        table.add_row(concept, variant, str(n), *styled,
                      style="bold" if variant == statistics.POOLED else None, end_section=last)
    return table


def write_audit(
    cue_rows: Sequence[Mapping[str, Any]],
    out_dir: str | Path,
    model_rows: Sequence[Mapping[str, Any]] | None = None,
    title: str = "Cue audit",
    correlation_rows: Sequence[Mapping[str, Any]] | None = None,
    **metadata: Any,
) -> Path:
    """Write ``out_dir/cues.md`` (the compact table, beside the model's rows when given, then
    the model-cue correlations when given), ``cues.csv`` (every column of every row),
    ``cue_correlations.csv`` (with correlations) and ``cues.json`` (rows, correlations and
    ``metadata``)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    markdown = format_markdown(cue_rows, model_rows, title)
    if correlation_rows is not None:
        markdown += "\n" + format_correlations(correlation_rows)
        with open(out / "cue_correlations.csv", "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=CORRELATION_COLUMNS)
            writer.writeheader()
            writer.writerows(correlation_rows)
    (out / "cues.md").write_text(markdown)
    with open(out / "cues.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CUE_COLUMNS)
        writer.writeheader()
        writer.writerows(cue_rows)
    document = {**metadata, "cues": list(CUES),
                "rows": [json_row(row) for row in cue_rows]}
    if correlation_rows is not None:
        document["model_correlations"] = [json_row(row) for row in correlation_rows]
    (out / "cues.json").write_text(json.dumps(document, indent=2) + "\n")
    return out


# ----------------------------------------------------------------------------- command line


def audit(
    root: Path,
    split: Literal["val", "test", "generalization"] = "test",
    concepts: list[specs.Concept] | None = None,
    out: Path | None = None,
    alpha: float = statistics.ALPHA,
    batch_size: int = 64,
    num_workers: int = 0,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Physics-blind cue scores of a probe split, with the model's paired statistics.

    Prints the table (M, t, p, d_z, accuracy and pooled rows per cue) and writes cues.md,
    cues.csv and cues.json; returns the rows.

    Args:
        root: dataset folder (a generated store).
        split: probe split to audit.
        concepts: concepts to audit (default: every concept in the store).
        out: output folder (default: ROOT/cue_audit/SPLIT).
        alpha: significance level (default: configs/base.yaml's alpha).
        batch_size: pairs scored at once.
        num_workers: data loader worker processes.
        progress: show a progress bar.
    """
    from rich.console import Console

    statistics.check_alpha(alpha)
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    scores = audit_split(root, split, concepts, batch_size, num_workers, progress=progress)
    rows = scores.rows(alpha=alpha)
    title = f"Cue audit of {root} ({split} split, {len(scores)} pairs)"
    out = write_audit(rows, out or Path(root) / "cue_audit" / split, title=title, root=str(root),
                      split=split, alpha=alpha, num_pairs=len(scores))
    console = Console()
    if not console.is_terminal:  # logs and pipes: do not cut the table at 80 columns
        console.width = 140
    console.print(cue_table(rows, title=title))
    print(f"cue audit written to {out} (cues.md, cues.csv, cues.json)")
    return rows
