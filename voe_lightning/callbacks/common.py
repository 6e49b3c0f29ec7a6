"""What the callbacks share: the probe DataModule's concept and variant names, and
objects gathered from every DDP rank."""

from __future__ import annotations

from typing import Any

import lightning as L

from voe_lightning.probe_datamodule import probe_datamodule


def probe_names(trainer: L.Trainer, user: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The DataModule's concept and variant names (refused unless it is a ProbeDataModule)."""
    datamodule = probe_datamodule(trainer, user)
    return tuple(datamodule.concept_names), tuple(datamodule.variant_names)


def gather_objects(value: Any) -> list[Any]:
    """All ranks' values under torch.distributed (DDP test), else [value]."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1:
        gathered: list[Any] = [None] * dist.get_world_size()
        dist.all_gather_object(gathered, value)
        return gathered
    return [value]
