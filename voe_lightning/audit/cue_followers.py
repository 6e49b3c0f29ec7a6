"""How a physics-blind model may turn a cue into surprise (``FOLLOWERS``): the synthetic
followers the verdict's calibration (``calibration``) holds it against, each a per-pair term
from the real cue scores of a concept's probe pairs."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["FOLLOWERS", "Follower", "Scores"]

#: A cue follower: per-pair term from the pairs' scores (consistent, inconsistent) and the
#: concept's scale of score differences, scale of scores and mean score.
Follower = Callable[[np.ndarray, np.ndarray, float, float, float], np.ndarray]
#: Per-pair scores or terms, float64 [pairs].
Scores = npt.NDArray[np.float64]


def _linear(
    con: Scores, inc: Scores, difference_scale: float, score_scale: float, score_mean: float
) -> Scores:
    """z: the cue difference in SDs of the concept's differences."""
    return (inc - con) / difference_scale


def _tanh(*scores: Any) -> Scores:
    return np.tanh(_linear(*scores))


def _signed_square(*scores: Any) -> Scores:
    z = _linear(*scores)
    return z * np.abs(z)


def _threshold(*scores: Any) -> Scores:
    z = _linear(*scores)
    return np.sign(z) * (np.abs(z) > 0.5)


def _per_video_square(
    con: Scores, inc: Scores, difference_scale: float, score_scale: float, score_mean: float
) -> Scores:
    """u_inc^2 - u_con^2, u a video's score in SDs of the concept's scores from their mean."""
    return ((inc - score_mean) / score_scale) ** 2 - ((con - score_mean) / score_scale) ** 2


#: How a physics-blind model may turn a cue into surprise: odd functions of the pair's cue
#: difference z (linear; saturating; expanding; a detector that fires beyond half an SD), and a
#: per-video one, each video's surprise the square of its standardized score u (convex: the
#: difference u_inc^2 - u_con^2 need not cancel over mirrored variants).
FOLLOWERS: dict[str, Follower] = {
    "linear": _linear,
    "tanh": _tanh,
    "signed square": _signed_square,
    "threshold": _threshold,
    "per-video square": _per_video_square,
}
