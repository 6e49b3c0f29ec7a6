"""What can go wrong with a store, each error naming its file and the fix: a shard that is
missing, truncated, foreign or fails its checksums (``CorruptShardError``), a manifest that is
unreadable or no store's (``ManifestError``), and one written with other settings than a
``generate`` asks for (``ManifestMismatchError``). Below every other module of the store, so
that each can raise them (``files`` lets a ``CorruptShardError`` through as it is)."""

from __future__ import annotations

import errno
import os
from pathlib import Path


class CorruptShardError(OSError):
    """A shard that is missing, truncated or fails its checksums; ``path`` names it."""

    def __init__(self, path: str | os.PathLike[str], reason: str):
        self.path = Path(path)
        self.reason = reason
        super().__init__(errno.EIO, f"corrupt shard {self.path}: {reason}", str(self.path))

    def __str__(self) -> str:
        return (
            f"corrupt shard {self.path}: {self.reason} (rerun generate with this store's settings, "
            "or the fit/test using it, whose prepare_data regenerates bad shards)"
        )

    # Keep both arguments when sent back from a worker process.
    def __reduce__(self) -> tuple[type[CorruptShardError], tuple[str, str]]:
        return (type(self), (str(self.path), self.reason))


class ManifestError(ValueError):
    """A manifest that is unreadable or not a store's manifest; the message names the file."""


class ManifestMismatchError(ValueError):
    """The root already holds a dataset generated with other settings."""
