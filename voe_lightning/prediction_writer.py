"""``predict``'s output file: IntPhys' answer.txt from ``SurpriseModel.predict_step``'s
per-movie surprise, gathered from every DDP rank."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import BasePredictionWriter
from lightning.pytorch.utilities import rank_zero_info

from voe_lightning.benchmark_metrics import write_answer_file


class IntPhysAnswerWriter(BasePredictionWriter):
    """Writes the IntPhys challenge's ``answer.txt`` to ``path`` at the end of ``predict``: one
    line per movie of the predict dataset (its ``names[index]``, e.g. ``O1/0001/1``) with a
    plausibility from the movie's total surprise (``benchmark_metrics.write_answer_file``)."""

    def __init__(self, path: str | os.PathLike = "answer.txt"):
        super().__init__(write_interval="epoch")
        self.path = Path(path)

    def write_on_epoch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        predictions: Sequence[Any],
        batch_indices: Sequence[Any],
    ) -> None:
        scores = [
            (index, value)
            for batch in predictions
            for index, value in zip(batch["index"].tolist(), batch["surprise"].tolist())
        ]
        if trainer.world_size > 1:  # each rank scored its own movies: gather them on rank 0
            gathered: list[Any] = [None] * trainer.world_size
            torch.distributed.all_gather_object(gathered, scores)
            scores = [score for rank in gathered for score in rank]
        if not trainer.is_global_zero:
            return
        names = trainer.predict_dataloaders.dataset.names
        if sorted(index for index, _ in scores) != list(range(len(names))):
            raise RuntimeError(
                f"predict scored {len(scores)} movies ({len({i for i, _ in scores})} distinct) of "
                f"the {len(names)} in the predict dataset; every movie needs exactly one score"
            )
        write_answer_file(self.path, {names[index]: value for index, value in scores})
        rank_zero_info(f"wrote {self.path} ({len(names)} movies)")
