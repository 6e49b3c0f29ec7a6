"""The cue audit (DESIGN.md §4): physics-blind scores of each probe video, tested with the same
paired statistics as a model's surprise. A score that tells inconsistent from consistent videos
of a concept's pooled pairs is a low-level cue in the stimuli, not evidence of physics, so these
rows stand beside every model result.

Every score is computed on the frames after ``manipulation_frame`` (the two videos of a pair are
identical up to and including it), per video:

- ``foreground_pixels``: visible object pixels (mask id > 0), summed over frames;
- ``motion_energy``: mean absolute difference of consecutive frames, summed;
- ``copy_last_error``: mean squared error of predicting each frame by the one before;
- ``linear_extrapolation_error``: mean squared error of predicting x_t by 2 x_{t-1} - x_{t-2};
- ``pixel_novelty``: per pixel, the distance of its colour to the nearest colour seen at that
  place in any earlier frame, summed (something new appearing where it never was).

``accuracy`` here counts a tied pair as half (scores that cannot differ, such as visible pixels
under a pure colour change, sit at 0.5 = chance rather than 0)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from voe_lightning import specs, statistics

__all__ = ["CUES", "CueAudit", "audit_records", "cue_scores"]


def _frames(frames: Any) -> np.ndarray:
    array = frames.numpy() if hasattr(frames, "numpy") else np.asarray(frames)
    return array.astype(np.float32) / 255.0


def _foreground_pixels(frames: np.ndarray, mask: np.ndarray, m: int) -> float:
    return float((mask[m + 1 :] > 0).sum())


def _motion_energy(frames: np.ndarray, mask: np.ndarray, m: int) -> float:
    return float(np.abs(np.diff(frames[m:], axis=0)).mean(axis=(1, 2, 3)).sum())


def _copy_last_error(frames: np.ndarray, mask: np.ndarray, m: int) -> float:
    return float(np.square(np.diff(frames[m:], axis=0)).mean(axis=(1, 2, 3)).sum())


def _linear_extrapolation_error(frames: np.ndarray, mask: np.ndarray, m: int) -> float:
    start = max(m + 1, 2)
    if start >= len(frames):
        return 0.0
    predicted = np.clip(2.0 * frames[start - 1 : -1] - frames[start - 2 : -2], 0.0, 1.0)
    return float(np.square(frames[start:] - predicted).mean(axis=(1, 2, 3)).sum())


def _pixel_novelty(frames: np.ndarray, mask: np.ndarray, m: int) -> float:
    total = 0.0
    for t in range(m + 1, len(frames)):
        distance = np.abs(frames[:t] - frames[t]).sum(axis=-1)  # [t, H, W], L1 over channels
        total += float(distance.min(axis=0).sum())
    return total


#: The physics-blind scorers, each ``score(frames float [T,H,W,3] in [0,1], mask [T,H,W], m)``.
CUES: dict[str, Callable[[np.ndarray, np.ndarray, int], float]] = {
    "foreground_pixels": _foreground_pixels,
    "motion_energy": _motion_energy,
    "copy_last_error": _copy_last_error,
    "linear_extrapolation_error": _linear_extrapolation_error,
    "pixel_novelty": _pixel_novelty,
}


def cue_scores(frames: Any, mask: Any, manipulation_frame: int) -> dict[str, float]:
    """Every cue's score of one video (uint8 frames [T, H, W, 3], mask [T, H, W])."""
    array = _frames(frames)
    mask = mask.numpy() if hasattr(mask, "numpy") else np.asarray(mask)
    m = int(manipulation_frame)
    if not 0 <= m < len(array):
        raise ValueError(f"manipulation_frame must be in [0, {len(array) - 1}], got {m}")
    return {name: score(array, mask, m) for name, score in CUES.items()}


@dataclass
class CueAudit:
    """Per-pair cue scores of a probe split: ``scores[side][cue]`` float arrays over pairs
    (side is ``consistent`` or ``inconsistent``), with each pair's concept and variant."""

    concepts: np.ndarray
    variants: np.ndarray
    scores: dict[str, dict[str, np.ndarray]]

    def groups(self) -> list[tuple[str, str, np.ndarray]]:
        """(concept, variant, row selector) for every variant, and a ``pooled`` group for each
        concept with a counterbalanced pair (the union of its standard variants' pairs)."""
        groups = []
        for concept in dict.fromkeys(self.concepts.tolist()):
            in_concept = self.concepts == concept
            present = set(self.variants[in_concept].tolist())
            for variant in specs.PROBE_VARIANTS[concept]:
                if variant in present:
                    groups.append((concept, variant, in_concept & (self.variants == variant)))
            if "counterbalanced" in present and "standard" in present:
                pooled = in_concept & np.isin(self.variants, ["standard", "counterbalanced"])
                groups.append((concept, "pooled", pooled))
        return groups

    def rows(self, bootstrap: int = 0) -> list[dict[str, Any]]:
        """One row per (concept, variant or pooled, cue): the paired test of
        score(inconsistent) - score(consistent), with ``accuracy`` counting ties as half."""
        rows = []
        for concept, variant, selected in self.groups():
            for cue in CUES:
                inconsistent = self.scores["inconsistent"][cue][selected]
                consistent = self.scores["consistent"][cue][selected]
                row = {"concept": concept, "variant": variant, "cue": cue}
                if len(inconsistent) < 2:
                    row.update(n=len(inconsistent), note="fewer than 2 pairs")
                else:
                    result = statistics.paired_test(inconsistent, consistent, bootstrap=bootstrap)
                    row.update(result.as_dict())
                    d = inconsistent - consistent
                    row["accuracy"] = float(np.mean(d > 0) + 0.5 * np.mean(d == 0))
                rows.append(row)
        return rows


def audit_records(records: Iterable[Mapping[str, Any]], progress: bool = False) -> CueAudit:
    """Score every probe pair (unbatched probe records as in ``specs.probe_spec``)."""
    concepts, variants = [], []
    scores = {side: {cue: [] for cue in CUES} for side in ("consistent", "inconsistent")}
    if progress:
        from tqdm.auto import tqdm

        records = tqdm(records, desc="cue audit", unit="pair")
    for record in records:
        concepts.append(specs.concept_name(record))
        variants.append(specs.variant_name(record))
        m = int(record["manipulation_frame"])
        for side in scores:
            video_scores = cue_scores(record[side]["frames"], record[side]["mask"], m)
            for cue, value in video_scores.items():
                scores[side][cue].append(value)
    return CueAudit(
        np.array(concepts, dtype=object),
        np.array(variants, dtype=object),
        {side: {cue: np.array(v, np.float64) for cue, v in s.items()} for side, s in scores.items()},
    )
