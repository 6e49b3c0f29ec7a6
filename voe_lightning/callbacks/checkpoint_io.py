"""Checkpoints written whole: Lightning's ``TorchCheckpointIO`` stages a checkpoint in the
system's temporary folder (fsspec's transaction) and moves it into ``checkpoints/``; on another
file system that move is a copy, which a full disk cuts short, leaving a truncated
``epoch=...ckpt``. ``WholeCheckpointIO`` stages it beside its target instead, fsynced, and
renames it (``store.atomic_write``): a failed write leaves no checkpoint file, the
previous one of that name whole, and names the file; ``use_whole_checkpoints`` puts it in a
trainer's strategy (``InterruptCheckpoint.setup`` does, so every CLI run has it)."""

from __future__ import annotations

import io
import os
from typing import Any

import lightning as L
import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO

from voe_lightning.data.store import atomic_write


class WholeCheckpointIO(TorchCheckpointIO):
    """``TorchCheckpointIO`` whose local checkpoints are staged in their own folder and renamed
    into place (a remote ``scheme://`` path is Lightning's as before)."""

    def save_checkpoint(
        self, checkpoint: dict[str, Any], path: Any, storage_options: Any | None = None
    ) -> None:
        if storage_options is not None or "://" in str(path):
            super().save_checkpoint(checkpoint, path, storage_options)
            return
        buffer = io.BytesIO()
        torch.save(checkpoint, buffer)
        atomic_write(os.fspath(path), [buffer.getvalue()])


def use_whole_checkpoints(trainer: L.Trainer) -> None:
    """Give ``trainer``'s strategy a ``WholeCheckpointIO`` where it has Lightning's plain
    ``TorchCheckpointIO`` (a CheckpointIO of the user's own is kept)."""
    strategy = trainer.strategy
    if type(strategy.checkpoint_io) is TorchCheckpointIO:
        strategy.checkpoint_io = WholeCheckpointIO()
