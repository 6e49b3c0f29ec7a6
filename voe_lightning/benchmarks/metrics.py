"""The external benchmarks' published metrics, computed from model surprise
(docs/architecture.md §8).

IntPhys (Riochet et al. 2018, arXiv:1803.07616, eqs. 1-2, and the challenge's scoring program)
scores a plausibility P(x) per movie, in quadruplets of two possible and two impossible movies:

- relative error rate (``relative_error_rate``): share of quadruplets where the possible movies'
  summed plausibility is strictly below the impossible movies', as the challenge's scoring
  program (score.py) counts it; a tie is no error. With surprise S as implausibility: error when
  sum S(possible) > sum S(impossible). Impossible movies are made of the possible movies'
  frames, so any score summed frame by frame ties every quadruplet and scores a perfect 0 by
  this rule; ``relative_error_rate_ties_half`` counts a tie as half an error instead (chance is
  0.5), and is reported beside it.
- absolute error rate: 1 - AUC of telling possible from impossible movies by plausibility,
  over all movies of a block (threshold-free). Here ``auroc`` is that AUC, computed as the AUC
  of surprise for detecting impossible movies (the same number).

The DeepMind Physical Concepts probes come in the same 2 + 2 quadruplets and get the same
metrics per concept. Matched possible/impossible pairs also get our one-tailed paired t-test
(``voe_lightning.stats.statistics.paired_test``, inconsistent = impossible).

The quadruplet benchmarks' pairs also get the field's metric set (``field_metrics``) under
``field_metrics``, each group its own threshold.

IntPhys 2 (Bordes et al. 2025) is scored as the V-JEPA intuitive-physics evaluation (Garrido et
al. 2025) scores it, over Possible/Impossible pairs of one scene and prefix
(``intphys2_metrics``): the field's metric set (``voe_lightning.stats.field_metrics``: relative
accuracy and AUROC with sum, mean and max surprise, absolute accuracy) at one threshold for
every group, the 90th percentile of the possible videos' max surprise over the whole split, so
the group rows are what the one classifier gets there, and the same threshold turns Held-Out
surprise into the leaderboard's answers.

Submissions: ``answer.txt`` holds one ``<movie path> <plausibility>`` line per movie, paths
relative to the test folder (``O1/0001/1 0.9751``), 0 <= P <= 1. ``plausibility_from_surprise``
maps surprise to P by a decreasing affine map over the whole submission, which preserves every
comparison both metrics make (each quadruplet sums two movies per side), so the official scores
of the file equal the ones computed here from surprise.
"""

from __future__ import annotations

import math
import os
import re
from collections import Counter, defaultdict
from collections.abc import Hashable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from voe_lightning.benchmarks.reader import read_text
from voe_lightning.data.store import write_whole
from voe_lightning.stats.field_metrics import (
    PERCENTILE,
    field_metrics,
    reduce_surprise,
    surprise_threshold,
)
from voe_lightning.stats.statistics import paired_test, ranked_auroc

#: A movie path in an IntPhys answer file: <block>/<scene>/<movie 1-4>.
ANSWER_PATH = re.compile(r"^(O[123])/([^/\s]+)/([1-4])$")


def relative_error_rate(
    surprise_possible: Any, surprise_impossible: Any, tie_weight: float = 0.0
) -> float:
    """IntPhys relative error rate over quadruplets: ``surprise_possible`` and
    ``surprise_impossible`` are [Q, k] (each row: one quadruplet's possible / impossible movies'
    surprise). A quadruplet is an error when its possible movies' summed surprise strictly
    exceeds the impossible ones' (the challenge's rule); a tie counts ``tie_weight`` of an error
    (0.5 for ``relative_error_rate_ties_half``)."""
    possible = np.atleast_2d(np.asarray(surprise_possible, dtype=np.float64)).sum(axis=1)
    impossible = np.atleast_2d(np.asarray(surprise_impossible, dtype=np.float64)).sum(axis=1)
    if possible.shape != impossible.shape or possible.size == 0:
        raise ValueError(
            f"need the same number (>0) of quadruplets on both sides, got {possible.size} "
            f"possible and {impossible.size} impossible rows"
        )
    errors = (possible > impossible) + tie_weight * (possible == impossible)
    return float(errors.mean())


def auroc(surprise: Any, is_possible: Any) -> float:
    """Area under the ROC curve of surprise for telling impossible movies (positive) from
    possible ones; ties count half. Equals the IntPhys AUC of plausibility for possible."""
    surprise = np.asarray(surprise, dtype=np.float64).ravel()
    labels = np.asarray(is_possible, dtype=bool).ravel()
    if surprise.shape != labels.shape:
        raise ValueError(f"{surprise.size} surprise values for {labels.size} labels")
    if labels.all() or not labels.any():
        raise ValueError("AUROC needs both possible and impossible movies")
    return ranked_auroc(surprise[~labels], surprise[labels])


def absolute_error_rate(surprise: Any, is_possible: Any) -> float:
    """IntPhys absolute error rate: 1 - AUC over all movies (threshold-free)."""
    return 1.0 - auroc(surprise, is_possible)


def quadruplet_metrics(
    quadruplet: Sequence[int] | np.ndarray,
    surprise_possible: Any,
    surprise_impossible: Any,
    alpha: float,
    bootstrap: int = 2000,
) -> dict[str, Any]:
    """Metrics of matched pairs (one row per pair: its quadruplet id, the possible movie's and
    the impossible movie's surprise, per frame [N, T] or as totals [N]): relative error rate
    (the challenge's rule, and with ties counted half), absolute error rate and AUROC of total
    surprise (the sum over frames), the paired t-test of S(impossible) - S(possible) over pairs
    and, given per-frame surprise, the field's metric set (``field_metrics``)."""
    quadruplet = np.asarray(quadruplet).ravel()
    frames = _per_frame_or_none(surprise_possible, surprise_impossible)
    possible, impossible = (
        (reduce_surprise(side, "sum") for side in frames)
        if frames
        else (
            np.asarray(side, dtype=np.float64).ravel()
            for side in (surprise_possible, surprise_impossible)
        )
    )
    if not quadruplet.size == possible.size == impossible.size:
        raise ValueError(
            f"one quadruplet id per pair: got {quadruplet.size} ids, {possible.size} possible "
            f"and {impossible.size} impossible surprises"
        )
    if quadruplet.size == 0:
        raise ValueError("no pairs to score")
    sums: defaultdict[int, list[float]] = defaultdict(lambda: [0.0, 0.0])
    for key, p, i in zip(quadruplet.tolist(), possible, impossible):
        sums[key][0] += p
        sums[key][1] += i
    per_quadruplet = np.array(list(sums.values()))
    movies = np.concatenate([possible, impossible])
    labels = np.concatenate([np.ones(possible.size, bool), np.zeros(impossible.size, bool)])
    area = auroc(movies, labels)
    result: dict[str, Any] = {
        "n_quadruplets": len(sums),
        "n_pairs": int(possible.size),
        "relative_error_rate": relative_error_rate(per_quadruplet[:, :1], per_quadruplet[:, 1:]),
        "relative_error_rate_ties_half": relative_error_rate(
            per_quadruplet[:, :1], per_quadruplet[:, 1:], tie_weight=0.5
        ),
        "absolute_error_rate": 1.0 - area,
        "auroc": area,
    }
    result["paired_test"] = _paired_test(impossible, possible, alpha, bootstrap)
    if frames is not None:
        result["field_metrics"] = field_metrics(*frames)
    return result


def _paired_test(
    impossible: np.ndarray, possible: np.ndarray, alpha: float, bootstrap: int
) -> dict[str, Any]:
    """The one-tailed paired t-test of S(impossible) - S(possible) over pairs, as a dict (a note
    instead below 2 pairs)."""
    if possible.size < 2:
        return {"n": int(possible.size), "note": "a paired t-test needs 2 pairs"}
    return paired_test(impossible, possible, alpha=alpha, bootstrap=bootstrap).as_dict()


def _per_frame_or_none(
    surprise_possible: Any, surprise_impossible: Any
) -> tuple[np.ndarray, np.ndarray] | None:
    """Both sides as float64 per-frame surprise [N, T] when they are two-dimensional, else
    None (totals)."""
    possible, impossible = (
        np.asarray(side, dtype=np.float64) for side in (surprise_possible, surprise_impossible)
    )
    return (possible, impossible) if possible.ndim == 2 and impossible.ndim == 2 else None


def pair_surprise(outputs: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pair's seed (IntPhys and Physical Concepts: its quadruplet) and its possible
    (consistent) and impossible (inconsistent) video's per-frame surprise [N, T] in float64,
    from collected
    ``probe_step`` outputs (seed, surprise_consistent, surprise_inconsistent [N, T])."""
    seeds = torch.as_tensor(outputs["seed"]).cpu().numpy().ravel()
    possible, impossible = (
        torch.as_tensor(outputs[f"surprise_{side}"]).double().cpu().numpy()
        for side in ("consistent", "inconsistent")
    )
    return seeds, possible, impossible


def incomplete_quadruplets(quadruplets: Iterable[Hashable]) -> int:
    """How many quadruplets (one key per scored pair) lack one of their two pairs."""
    return sum(1 for pairs in Counter(quadruplets).values() if pairs != 2)


def grouped_metrics(
    groups: Sequence[str],
    quadruplet: Sequence[int] | np.ndarray,
    surprise_possible: Any,
    surprise_impossible: Any,
    subgroups: Sequence[str | None] | None = None,
    *,
    alpha: float,
    **options: Any,
) -> dict[str, dict[str, dict[str, Any]]]:
    """``quadruplet_metrics`` per group (IntPhys block, Physical Concepts concept) under
    ``all``, and per subgroup (e.g. IntPhys visible / occluded) under its name; surprise per
    pair as ``quadruplet_metrics`` takes it (per frame [N, T] or totals [N])."""
    groups = list(groups)
    quadruplet = np.asarray(quadruplet).ravel()
    possible = np.asarray(surprise_possible, dtype=np.float64)
    impossible = np.asarray(surprise_impossible, dtype=np.float64)
    subgroups = list(subgroups) if subgroups is not None else [None] * len(groups)
    if not len(groups) == len(subgroups) == quadruplet.size == len(possible) == len(impossible):
        raise ValueError("groups, subgroups, quadruplet ids and surprises need one entry per pair")
    result: dict[str, dict[str, dict[str, Any]]] = {}
    for group in sorted(set(groups)):
        rows = np.array([g == group for g in groups])
        result[group] = {
            "all": quadruplet_metrics(
                quadruplet[rows], possible[rows], impossible[rows], alpha=alpha, **options
            )
        }
        for subgroup in sorted({s for s, r in zip(subgroups, rows) if r and s is not None}):
            sub = rows & np.array([s == subgroup for s in subgroups])
            result[group][subgroup] = quadruplet_metrics(
                quadruplet[sub], possible[sub], impossible[sub], alpha=alpha, **options
            )
    return result


# --- answer files -------------------------------------------------------------------------------
def plausibility_from_surprise(surprise: Any) -> np.ndarray:
    """Plausibility in [0, 1] from surprise by the decreasing affine map min -> 1, max -> 0 over
    all given movies (0.5 for all when every surprise is equal): IntPhys' relative and
    absolute errors of the result equal those of the surprise."""
    surprise = np.asarray(surprise, dtype=np.float64)
    if not np.isfinite(surprise).all():
        raise ValueError("surprise must be finite to be written as plausibility")
    low, high = surprise.min(initial=np.inf), surprise.max(initial=-np.inf)
    if surprise.size == 0 or high == low:
        return np.full(surprise.shape, 0.5)
    plausibility: np.ndarray = (high - surprise) / (high - low)
    return plausibility


def _check_movie_path(path: str, where: str) -> re.Match[str]:
    match = ANSWER_PATH.match(path)
    if match is None:
        raise ValueError(
            f"{where}: movie path {path!r} is not <block>/<scene>/<movie>, e.g. O1/0001/1 "
            "(block O1, O2 or O3; movie 1 to 4)"
        )
    return match


def _check_complete(scenes: Mapping[str, set[str]], where: str) -> None:
    for scene, movies in sorted(scenes.items()):
        if movies != {"1", "2", "3", "4"}:
            raise ValueError(
                f"{where}: scene {scene} has movies {sorted(movies)}; every scene needs 1, 2, 3 and 4"
            )


def write_answer_file(path: str | os.PathLike[str], surprise: Mapping[str, float]) -> Path:
    """Write an IntPhys ``answer.txt`` from each movie's total surprise (keys: movie paths
    relative to the split folder, ``O1/0001/1``): one ``<path> <plausibility>`` line per movie,
    sorted, plausibility from ``plausibility_from_surprise`` written exactly (``repr``: a
    rounded value can turn a tie of two movies' sums into an error, so the official score of
    the file would not be the report's). Every scene must have its 4 movies."""
    path = Path(path)
    movies = sorted(surprise)
    scenes: dict[str, set[str]] = defaultdict(set)
    for movie in movies:
        match = _check_movie_path(movie, str(path))
        scenes[f"{match[1]}/{match[2]}"].add(match[3])
    _check_complete(scenes, str(path))
    plausibility = plausibility_from_surprise([surprise[m] for m in movies])
    write_whole({path: "".join(f"{m} {float(p)!r}\n" for m, p in zip(movies, plausibility))})
    return path


def read_answer_file(path: str | os.PathLike[str]) -> dict[str, float]:
    """Read and validate an IntPhys ``answer.txt``: {movie path: plausibility}."""
    path = Path(path)
    answers: dict[str, float] = {}
    scenes: dict[str, set[str]] = defaultdict(set)
    text = read_text(path, hint="write it as UTF-8, as write_answer_file does")
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split()
        where = f"{path}, line {number}"
        if len(fields) != 2:
            raise ValueError(f"{where}: expected '<movie path> <plausibility>', got {line!r}")
        match = _check_movie_path(fields[0], where)
        try:
            value = float(fields[1])
        except ValueError:
            raise ValueError(f"{where}: plausibility {fields[1]!r} is not a number") from None
        if not 0.0 <= value <= 1.0 or math.isnan(value):
            raise ValueError(f"{where}: plausibility {value} is outside [0, 1]")
        if fields[0] in answers:
            raise ValueError(f"{where}: movie {fields[0]} appears twice")
        answers[fields[0]] = value
        scenes[f"{match[1]}/{match[2]}"].add(match[3])
    _check_complete(scenes, str(path))
    return answers


def score_answers(
    plausibility: Mapping[str, float], is_possible: Mapping[str, bool]
) -> dict[str, dict[str, dict[str, float]]]:
    """IntPhys scores of an answer (movie path -> plausibility) against labels (movie path ->
    possible), as the challenge computes them (plus ``relative_error_rate_ties_half``): per block, for ``all`` scenes and for the
    ``visible`` / ``occluded`` ones when scene names carry that condition."""
    if set(plausibility) != set(is_possible):
        missing = sorted(set(is_possible) - set(plausibility))[:3]
        extra = sorted(set(plausibility) - set(is_possible))[:3]
        raise ValueError(
            f"answer and labels name different movies (missing {missing}, extra {extra})"
        )
    scenes: dict[str, list[str]] = defaultdict(list)
    for movie in plausibility:
        scenes[movie.rsplit("/", 1)[0]].append(movie)
    result: dict[str, dict[str, dict[str, float]]] = {}
    for block in sorted({scene.split("/", 1)[0] for scene in scenes}):
        result[block] = {}
        for condition in ("all", "visible", "occluded"):
            chosen = [
                s
                for s in scenes
                if s.startswith(block + "/") and (condition == "all" or condition in s)
            ]
            if not chosen:
                continue
            movies = [m for s in chosen for m in scenes[s]]
            # plausibility is the opposite of surprise: negate to reuse the surprise forms
            rows = [
                (
                    [-plausibility[m] for m in scenes[s] if is_possible[m]],
                    [-plausibility[m] for m in scenes[s] if not is_possible[m]],
                )
                for s in chosen
            ]
            sums = ([[sum(p)] for p, _ in rows], [[sum(i)] for _, i in rows])
            result[block][condition] = {
                "relative_error_rate": relative_error_rate(*sums),
                "relative_error_rate_ties_half": relative_error_rate(*sums, tie_weight=0.5),
                "absolute_error_rate": absolute_error_rate(
                    [-plausibility[m] for m in movies], [is_possible[m] for m in movies]
                ),
            }
    return result


# --- IntPhys 2 ----------------------------------------------------------------------------------
def video_pair_metrics(
    frames_possible: Any,
    frames_impossible: Any,
    threshold: float,
    alpha: float,
    bootstrap: int = 2000,
) -> dict[str, Any]:
    """IntPhys 2 metrics of matched pairs from per-frame surprise [N, T] of each pair's possible
    and impossible video: the field's metric set (``field_metrics.field_metrics``) at a given
    absolute ``threshold``, with the paired t-test of S(impossible) - S(possible) over pairs
    (S summed over frames, as in our probe reports)."""
    result = field_metrics(frames_possible, frames_impossible, threshold)
    result["paired_test"] = _paired_test(
        reduce_surprise(frames_impossible, "sum"),
        reduce_surprise(frames_possible, "sum"),
        alpha,
        bootstrap,
    )
    return result


def intphys2_metrics(
    principle: Sequence[str],
    difficulty: Sequence[str],
    camera: Sequence[str],
    frames_possible: Any,
    frames_impossible: Any,
    percentile: float = PERCENTILE,
    *,
    alpha: float,
    **options: Any,
) -> dict[str, Any]:
    """``video_pair_metrics`` over all pairs (``all``), per principle (``principle``) and per
    principle x difficulty x camera (``principle_difficulty_camera``, keyed
    ``<principle>/<difficulty>/<camera>``), at one threshold from all possible videos
    (``threshold``). ``alpha`` and ``options`` (bootstrap) go to ``video_pair_metrics``."""
    possible = np.asarray(frames_possible, dtype=np.float64)
    impossible = np.asarray(frames_impossible, dtype=np.float64)
    keys = list(zip(principle, difficulty, camera))
    if len(keys) != len(possible) or len(possible) != len(impossible):
        raise ValueError(
            f"one principle, difficulty and camera per pair: got {len(keys)} "
            f"labels for {len(possible)} and {len(impossible)} pairs"
        )
    threshold = surprise_threshold(possible.max(axis=-1), percentile)

    def metrics(rows: np.ndarray) -> dict[str, Any]:
        return video_pair_metrics(
            possible[rows], impossible[rows], threshold, alpha=alpha, **options
        )

    return {
        "threshold": {
            "value": threshold,
            "percentile": percentile,
            "of": "max per-frame surprise of the possible videos",
        },
        "all": metrics(np.ones(len(keys), bool)),
        "principle": {
            p: metrics(np.array([k[0] == p for k in keys])) for p in sorted({k[0] for k in keys})
        },
        "principle_difficulty_camera": {
            "/".join(key): metrics(np.array([k == key for k in keys])) for key in sorted(set(keys))
        },
    }
