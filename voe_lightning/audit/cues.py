"""The cue audit (docs/architecture.md §4, §8): physics-blind scores of each probe video, tested
with the same paired statistics as a model's surprise. A score that tells inconsistent from
consistent videos of a concept's pooled pairs is a low-level cue in the stimuli, not evidence of
physics, so these rows stand beside every model result (``test`` writes them to
``voe_report/cues.*``) and ``python -m voe_lightning audit --root DIR`` runs them on any probe split
of a store. Here: the scores of probe pairs and their tests (``CueAudit``); each cue's value
per frame and score per video are in ``voe_lightning.audit.video_cues``, the tables and files
they are written to, and the ``audit`` command, in ``voe_lightning.audit.cue_report``.

A pair whose masks are all zero in both videos (benchmarks without masks, e.g. IntPhys) has no
``foreground_pixels`` score; its rows say so instead of testing zeros.

``accuracy`` here counts a tied pair as half (scores that cannot differ, such as visible pixels
under a pure colour change, sit at 0.5 = chance rather than 0); ``p_two_sided`` flags a cue
that separates the pairs in either direction."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from scipy import stats

from voe_lightning import specs
from voe_lightning.audit import followers as object_followers
from voe_lightning.audit.video_cues import (
    CUES,
    FRAME_LOCAL_CUES,
    MASK_CUES,
    frames_after,
    score_videos,
)
from voe_lightning.stats import statistics, verdicts

if TYPE_CHECKING:
    from tensordict import TensorDict

__all__ = [
    "CUE_COLUMNS",
    "CueAudit",
    "audit_records",
    "audit_split",
    "physics_perfect_surprise",
    "seen_extent",
    "tracked_cues",
]

#: Short column titles of the compact tables.
CUE_TITLES = {
    "foreground_pixels": "foreground",
    "motion_energy": "motion",
    "copy_last_error": "copy-last",
    "linear_extrapolation_error": "lin. extrap.",
    "pixel_novelty": "novelty",
}
SIDES = ("consistent", "inconsistent")
#: Columns of cues.csv, in order (``None`` cells mean "no test", explained in ``note``).
CUE_COLUMNS = (
    ("concept", "variant", "cue")
    + tuple(f for f in statistics.QuadrupletTestResult.__dataclass_fields__ if f != "note")
    + ("p_two_sided", "note")
)
#: Columns of cue_correlations.csv (``CueAudit.model_correlations``).
CORRELATION_COLUMNS = ("concept", "variant", "cue", "n", "r", "p_two_sided", "alpha", "note")
#: The variant name of a pooled group's correlation within its variants (``model_correlations``).
WITHIN_VARIANTS = "pooled within variants"
#: The variant name of a pooled group's correlation within its variants given how much of each
#: pair's difference is seen (``seen_extent``; ``model_correlations``).
GIVEN_EXTENT = "within variants, given the seen extent"
#: The columns of ``seen_extent``.
EXTENT_COLUMNS = ("parted", "first_parted", "seen")
#: The variant name of a pooled group's reference row: the physics-perfect observer's own r
#: with each cue within variants (``physics_perfect_surprise``; ``model_correlations``).
PHYSICS_PERFECT = "physics-perfect observer, within variants"
#: What costs the physics-perfect observer as much as an object-frame seen in one video only:
#: this many metres between an object's two positions, or radians between its orientations.
STATE_SCALE = 0.05


def seen_extent(
    inconsistent: torch.Tensor, consistent: torch.Tensor, manipulation_frame: torch.Tensor
) -> np.ndarray:
    """How much of each pair's difference is seen, in object-frames rather than pixels, from the
    two videos' ``objects`` ``visible_fraction`` [B, T, K], after the manipulation frame [B]:
    the object-frames seen in one video and not the other, the frames until the first of them
    (the frames left if none), and the seen object-frames, inconsistent less consistent;
    float64 [B, 3] (``EXTENT_COLUMNS``). The pixels would be the foreground cue itself: a model
    whose surprise grows with how long or how much of a violation it sees follows the cues
    that count it, whatever its physics."""
    seen = [(fraction > 0) for fraction in (inconsistent, consistent)]
    frames = seen[0].shape[1]
    m = torch.as_tensor(manipulation_frame, device=seen[0].device).reshape(-1, 1)
    after = frames_after(m, frames)
    parted = ((seen[0] != seen[1]) & after[..., None]).sum(-1)  # [B, T]
    index = torch.arange(frames, device=m.device)[None]
    first = torch.where(parted > 0, index, frames).amin(1) - m[:, 0] - 1  # from frame m + 1
    counted = [(side & after[..., None]).sum((1, 2)) for side in seen]
    return torch.stack([parted.sum(1), first, counted[0] - counted[1]], 1).double().cpu().numpy()


def physics_perfect_surprise(
    inconsistent: Any, consistent: Any, manipulation_frame: torch.Tensor
) -> np.ndarray:
    """The relative surprise of an observer with perfect physics and perception, from the two
    videos' ``objects`` (``position`` [B, T, K, 3], ``orientation`` [B, T, K, 4],
    ``visible_fraction`` [B, T, K]): it expects what the consistent video shows (physics from
    the shared first frames) and pays, after the manipulation frame, 1 for each object-frame
    seen in one video only and, for an object seen in both, the distance between its two states
    (metres of position plus radians of rotation, in ``STATE_SCALE``); float64 [B]. Its r with
    the cues is what physics alone gives on the probes: the reference for a model's."""
    seen = [side["visible_fraction"] > 0 for side in (inconsistent, consistent)]
    m = torch.as_tensor(manipulation_frame, device=seen[0].device)
    after = frames_after(m, seen[0].shape[1])[..., None]  # [B, T, 1]
    moved = (inconsistent["position"] - consistent["position"]).double().norm(dim=-1)
    alignment = (inconsistent["orientation"].double() * consistent["orientation"].double()).sum(-1)
    turned = 2.0 * torch.arccos(alignment.abs().clamp(max=1.0))
    both = seen[0] & seen[1] & after
    parted = (seen[0] != seen[1]) & after
    cost: torch.Tensor = parted.double() + torch.where(both, (moved + turned) / STATE_SCALE, 0.0)
    return cost.sum((1, 2)).cpu().numpy()


def _concatenated(parts: Sequence[np.ndarray | None]) -> np.ndarray | None:
    """``parts`` end to end; None unless every part is known."""
    known = [part for part in parts if part is not None]
    return np.concatenate(known) if len(known) == len(parts) else None


def _mask(video: Any) -> torch.Tensor | None:
    return video["mask"] if "mask" in video.keys() else None


@dataclass(frozen=True, eq=False)
class CueAudit:
    """Per-pair cue scores of probe pairs: ``scores[side][cue]`` float64 arrays over pairs
    (side is ``consistent`` or ``inconsistent``; NaN where a cue cannot be scored), with each
    pair's concept and variant name and, where the records carry object states, its
    ``seen_extent`` [N, 3] and ``physics_perfect_surprise`` [N] (else None); ``seeds`` [N]
    (None where unknown) match a quadruplet concept's two halves (``verdicts.quadruplets``).
    The cues are ``video_cues.CUES``, then the followers of a model's inputs where asked for
    (``audit.followers``)."""

    concepts: np.ndarray
    variants: np.ndarray
    scores: dict[str, dict[str, np.ndarray]]
    extent: np.ndarray | None = None
    physics_perfect: np.ndarray | None = None
    seeds: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.concepts)

    @property
    def cue_names(self) -> tuple[str, ...]:
        """The cues scored, in table order: the pixel cues, then any followers."""
        return tuple(self.scores["consistent"])

    @classmethod
    def score_batch(
        cls,
        batch: Any,
        concept_names: Sequence[str] = specs.CONCEPTS,
        variant_names: Sequence[str] = specs.VARIANTS,
        followers: Sequence[str] = (),
    ) -> CueAudit:
        """Score a batch of probe pairs (a stacked probe TensorDict, as loaders yield them);
        ``concept``/``variant`` indices decode with the given name tuples. A pair whose masks
        are all zero in both videos gets NaN ``foreground_pixels`` (no masks to count).
        ``followers`` (``states``, ``masks``) adds those followers' scores
        (``audit.followers.score``)."""
        m = batch["manipulation_frame"]
        scores = {
            side: score_videos(batch[side]["frames"], _mask(batch[side]), m) for side in SIDES
        }
        masks = [_mask(batch[side]) for side in SIDES]
        present = [mask for mask in masks if mask is not None]
        if len(present) == len(masks):
            unmasked = ~torch.stack([(mask != 0).flatten(1).any(dim=1) for mask in present]).any(
                dim=0
            )
            for side in SIDES:
                for cue in MASK_CUES:
                    scores[side][cue][unmasked] = math.nan
        numbers = {
            side: {
                **{cue: values.cpu().numpy() for cue, values in scores[side].items()},
                **object_followers.score(batch[side], m, followers),
            }
            for side in SIDES
        }
        extent = physics_perfect = None
        if all("objects" in batch[side].keys() for side in SIDES):
            inconsistent, consistent = (
                batch[side]["objects"] for side in ("inconsistent", "consistent")
            )
            extent = seen_extent(
                inconsistent["visible_fraction"], consistent["visible_fraction"], m
            )
            physics_perfect = physics_perfect_surprise(inconsistent, consistent, m)
        return cls(
            np.array([concept_names[int(i)] for i in batch["concept"].reshape(-1)], dtype=object),
            np.array([variant_names[int(i)] for i in batch["variant"].reshape(-1)], dtype=object),
            numbers,
            extent,
            physics_perfect,
            batch["seed"].reshape(-1).cpu().numpy() if "seed" in batch.keys() else None,
        )

    @classmethod
    def concatenate(cls, audits: Iterable[CueAudit]) -> CueAudit:
        """One audit of all the pairs of ``audits``, in order."""
        audits = list(audits)
        if not audits:
            raise ValueError("no cue scores to concatenate (no probe pairs were scored)")
        names = audits[0].cue_names
        return cls(
            np.concatenate([a.concepts for a in audits]),
            np.concatenate([a.variants for a in audits]),
            {
                side: {cue: np.concatenate([a.scores[side][cue] for a in audits]) for cue in names}
                for side in SIDES
            },
            *(
                _concatenated(parts)
                for parts in (
                    [a.extent for a in audits],
                    [a.physics_perfect for a in audits],
                    [a.seeds for a in audits],
                )
            ),
        )

    def groups(self) -> list[tuple[str, str, np.ndarray]]:
        """(concept, variant, row selector) for every variant, a ``pooled`` group for each
        concept with a counterbalanced pair and, where seeds are known, a group per quadruplet
        of ``specs.QUADRUPLETS`` (``verdicts.pair_groups``)."""
        return verdicts.pair_groups(self.concepts, self.variants, seeds=self.seeds)

    def rows(self, alpha: float, bootstrap: int = 0) -> list[dict[str, Any]]:
        """One row per (concept, variant or pooled, cue), columns ``CUE_COLUMNS``: the test
        of score(inconsistent) - score(consistent) the model's rows get
        (``statistics.group_test``: stratified for pooled), ``accuracy`` counting ties as half;
        every row, tested or not, carries ``alpha``."""
        rows = []
        for concept, variant, selected in self.groups():
            for cue in self.cue_names:
                inconsistent = self.scores["inconsistent"][cue][selected]
                consistent = self.scores["consistent"][cue][selected]
                row: dict[str, Any] = dict.fromkeys(CUE_COLUMNS)
                row.update(
                    concept=concept,
                    variant=variant,
                    cue=cue,
                    alpha=alpha,
                    n=len(self.concepts[selected])
                    // (2 if variant in specs.QUADRUPLET_ROWS else 1),
                )
                unscored = int(np.isnan(inconsistent).sum() + np.isnan(consistent).sum())
                untested = statistics.untested_reason(variant, self.variants[selected])
                if unscored:
                    row["note"] = (
                        f"{cue} skipped: {unscored} of {2 * row['n']} videos have no "
                        + ("object states" if cue.startswith("states_") else "object mask")
                        + " (all zero or absent)"
                    )
                elif untested:
                    row["note"] = untested
                else:
                    result = statistics.group_test(
                        variant,
                        inconsistent,
                        consistent,
                        self.variants[selected],
                        alpha=alpha,
                        bootstrap=bootstrap,
                    )
                    row.update(result.as_dict())
                    d = _differences(variant, inconsistent - consistent)
                    row["accuracy"] = float(np.mean(d > 0) + 0.5 * np.mean(d == 0))
                    row["p_two_sided"] = _two_sided(result.t, result.df)
                rows.append(row)
        return rows

    def model_correlations(
        self, model_difference: np.ndarray, alpha: float
    ) -> list[dict[str, Any]]:
        """How closely a model tracks each cue pair by pair: per group (``groups``) and cue,
        Pearson's r across pairs between the model's relative surprise d (``model_difference``,
        one per pair, in this audit's order) and the cue's d, with its two-sided p
        (``scipy.stats.pearsonr``). A model that follows a cue has r far from 0 even in a
        pooled group where its accuracy is at chance. Each pooled group also gets a row
        ``WITHIN_VARIANTS``: r after centring each variant's pairs on their own means (the
        partial correlation given the variant), which a model whose effect merely differs in
        size between the variants does not inflate; and, where the audit has each pair's
        ``extent``, a row ``GIVEN_EXTENT``: the partial correlation given, in each variant, how
        much of the violation is seen (``seen_extent``, a regression per variant), which a
        model whose surprise grows with the seen violation does not inflate either; and, where
        it has ``physics_perfect``, a row ``PHYSICS_PERFECT``: that observer's own r within
        variants, what physics alone gives on these pairs; columns ``CORRELATION_COLUMNS``."""
        model_difference = np.asarray(model_difference, dtype=np.float64)
        if model_difference.shape != (len(self),):
            raise ValueError(
                f"model_difference must hold one value per scored pair ({len(self)}), "
                f"got shape {model_difference.shape}"
            )
        differences = {
            cue: self.scores["inconsistent"][cue] - self.scores["consistent"][cue] for cue in CUES
        }
        rows = []
        for concept, variant, selected in self.groups():
            if variant in specs.QUADRUPLET_ROWS:  # correlations are pair by pair
                continue
            # (row name, d, covariates)
            readings: list[tuple[str, np.ndarray, np.ndarray | None]] = [
                (variant, model_difference, None)
            ]
            if variant == statistics.POOLED:
                within = np.empty((int(selected.sum()), 0))
                readings.append((WITHIN_VARIANTS, model_difference, within))
                if self.extent is not None:
                    readings.append((GIVEN_EXTENT, model_difference, self.extent[selected]))
                if self.physics_perfect is not None:
                    readings.append((PHYSICS_PERFECT, self.physics_perfect, within))
            for name, surprise, covariates in readings:
                labels = (
                    self.variants[selected]
                    if covariates is not None
                    else np.zeros(int(selected.sum()))
                )
                model, spent = _residuals(surprise[selected], labels, covariates)
                for cue in CUES:
                    cue_d, _ = _residuals(differences[cue][selected], labels, covariates)
                    row: dict[str, Any] = dict.fromkeys(CORRELATION_COLUMNS)
                    row.update(
                        concept=concept, variant=name, cue=cue, n=int(selected.sum()), alpha=alpha
                    )
                    df = row["n"] - 1 - spent  # the regressors spent, a mean per group at least
                    if np.isnan(cue_d).any() or np.isnan(model).any():
                        row["note"] = f"{cue} or the model's surprise is not scored for every pair"
                    elif df < 1:
                        row["note"] = f"only {row['n']} pairs: no correlation (needs at least 3)"
                    elif np.ptp(cue_d) == 0 or np.ptp(model) == 0:
                        row["note"] = "constant across pairs: r undefined"
                    else:
                        result = stats.pearsonr(model, cue_d)
                        row.update(
                            r=float(result.statistic),
                            p_two_sided=float(
                                _partial_p(result.statistic, df)
                                if covariates is not None
                                else result.pvalue
                            ),
                        )
                    rows.append(row)
        return rows


def _differences(variant: str, d: np.ndarray) -> np.ndarray:
    """The differences a group's test is over: per pair, or per quadruplet D, the sum of its
    halves (a quadruplet group holds its first halves, then its second halves)."""
    if variant not in specs.QUADRUPLET_ROWS:
        return d
    half = d.size // 2
    summed: np.ndarray = d[:half] + d[half:]
    return summed


def _residuals(
    values: np.ndarray, labels: np.ndarray, covariates: np.ndarray | None = None
) -> tuple[np.ndarray, int]:
    """``values`` less their least-squares fit, within each label's group (a variant's pairs),
    on a mean and the group's ``covariates`` [N, k] (none: the mean alone), and the number of
    regressors spent (the design's rank, summed over groups). A correlation over them is the
    one within groups, given the covariates: with groups of different means, r over the union
    is large whenever the model's effect and the cue's differ by group, whatever the model
    follows pair by pair."""
    values = np.asarray(values, dtype=np.float64)
    covariates = np.empty((len(values), 0)) if covariates is None else covariates
    residual, spent = values.copy(), 0
    for label in np.unique(labels):
        chosen = labels == label
        design = np.column_stack([np.ones(int(chosen.sum())), covariates[chosen]])
        if np.isnan(design).any() or np.isnan(values[chosen]).any():
            residual[chosen] = math.nan
            continue
        fit = np.linalg.lstsq(design, values[chosen], rcond=None)
        residual[chosen] -= design @ fit[0]
        spent += int(fit[2])
    return residual, spent


def _partial_p(r: float, df: int) -> float:
    """Two-sided p of a correlation ``r`` of group-centred values: Student's t with ``df``
    degrees of freedom, one fewer than ``scipy.stats.pearsonr``'s n - 2 for each further group
    whose mean was removed (the partial correlation given the group)."""
    if abs(r) >= 1.0:
        return 0.0
    p: float = 2 * stats.t.sf(abs(r) * math.sqrt(df / (1 - r * r)), df)
    return p


def tracked_cues(
    correlation_rows: Iterable[Mapping[str, Any]],
) -> dict[tuple[str, str], Mapping[str, Any]]:
    """Per (concept, variant) of ``CueAudit.model_correlations`` rows: the row of the
    frame-local cue whose r is largest in size (rows without an r are skipped)."""
    tracked: dict[tuple[str, str], Mapping[str, Any]] = {}
    for row in correlation_rows:
        key = (row["concept"], row["variant"])
        if (
            row["cue"] in FRAME_LOCAL_CUES
            and row["r"] is not None
            and (key not in tracked or abs(row["r"]) > abs(tracked[key]["r"]))
        ):
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
        raise ValueError(
            f"batch_size must be >= 0 (0: records are batches already), got {batch_size}"
        )
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
    ``root`` for ``concepts`` (default: every concept the store holds), each shard checked
    against the manifest first (``store.check_split``: a foreign one is refused)."""
    from torch.utils.data import ConcatDataset

    from voe_lightning.data import store

    if store.SPLIT_RECORD_TYPE.get(split) != "probe":
        probe_splits = [s for s, kind in store.SPLIT_RECORD_TYPE.items() if kind == "probe"]
        raise ValueError(
            f"split {split!r} holds no probe pairs; probe splits are: {', '.join(probe_splits)}"
        )
    manifest = store.read_manifest(root)
    if manifest is None:
        raise FileNotFoundError(
            f"no dataset at {root} (create one with `python -m voe_lightning "
            f"generate --root {root}`)"
        )
    concepts = list(dict.fromkeys(concepts or manifest["concepts"]))
    store.check_split(root, manifest, concepts, split)
    parts = [
        part
        for part in (store.open_split(root, concept, split) for concept in concepts)
        if len(part)
    ]
    if not parts:
        raise ValueError(
            f"the {split} split of {root} holds no probe pairs for "
            f"{', '.join(concepts)}; audit another split, or generate this one"
        )
    dataset: ConcatDataset[TensorDict] = ConcatDataset(parts)
    loader = store.record_loader(dataset, batch_size, num_workers)
    return audit_records(loader, batch_size=0, progress=progress, total=len(loader))
