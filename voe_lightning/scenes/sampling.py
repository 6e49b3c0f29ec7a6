"""Random draws of a scene: a seeded generator per (seed, concept, kind or variant), and redrawing
a sample that breaks a probe's constraints until one holds (deterministic for one seed)."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import TypeVar

import numpy as np

#: What a draw makes (a record, a quadruplet): ``draw_until_valid`` gives back what ``make`` does.
Drawn = TypeVar("Drawn")


def rng_for(seed: int, *salt: str) -> np.random.Generator:
    """A generator determined by ``seed`` and names (concept, kind or variant), so that the
    same seed in different concepts or kinds gives independent draws."""
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")
    words = [
        int.from_bytes(hashlib.blake2b(word.encode(), digest_size=8).digest(), "little")
        for word in salt
    ]
    return np.random.default_rng([seed, *words, len(salt)])


class RejectedSample(Exception):
    """A random draw that does not satisfy a probe's constraints; the caller draws again."""


class NoValidScene(RuntimeError):
    """Every draw of a scene was rejected (``draw_until_valid``): at the default video size a
    bug, in a frame too small or too narrow a setting the scenes cannot be drawn in
    (``data.store.render`` says which sizes work)."""


def draw_until_valid(
    make: Callable[[np.random.Generator], Drawn], rng: np.random.Generator, attempts: int = 50
) -> Drawn:
    """Call ``make(rng)`` until it does not raise RejectedSample (deterministic for one rng)."""
    last = None
    for _ in range(attempts):
        try:
            return make(rng)
        except RejectedSample as error:
            last = error
    raise NoValidScene(f"no valid scene after {attempts} draws; last rejection: {last}")
