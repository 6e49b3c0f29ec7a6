"""What a ``test`` report is made from (summary.json's ``source``, summary.md's first line)."""

from __future__ import annotations

from typing import Any

import lightning as L

from voe_lightning.probe_datamodule import probe_datamodule
from voe_lightning.runs import RunConfig


def report_source(trainer: L.Trainer, checkpoint_step: int | None, user: str) -> dict[str, Any]:
    """The checkpoint tested (None: the model as built) and its global step
    (``checkpoint_step``, as loaded), the DataModule's class, where its probes come from
    (``probe_source``: data root; ours, the seed offset and probe store too), the concepts of
    its test pairs, and the config file the CLI saved for this run (``runs.RunConfig``; None:
    none saved). ``user`` names the callback asking, should the DataModule not be a
    ProbeDataModule."""
    datamodule = probe_datamodule(trainer, user)
    configs = [
        callback.config_path
        for callback in trainer.callbacks  # type: ignore[attr-defined]  # lightning: set by the Trainer's CallbackConnector, undeclared on Trainer
        if isinstance(callback, RunConfig) and callback.config_path is not None
    ]
    return {
        "config": str(configs[0]) if configs else None,
        "checkpoint": str(trainer.ckpt_path) if trainer.ckpt_path else None,
        "global_step": checkpoint_step if trainer.ckpt_path else None,
        "datamodule": f"{type(datamodule).__module__}.{type(datamodule).__qualname__}",
        **datamodule.probe_source(),
        "concepts": sorted({concept for concept, _ in datamodule.probe_cases("test")}),
    }
