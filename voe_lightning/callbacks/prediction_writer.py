"""``predict``'s output files, from ``SurpriseModel.predict_step``'s per-video surprise gathered
from every DDP rank: IntPhys' answer.txt and the IntPhys 2 leaderboard's jsonl."""

from __future__ import annotations

import json
import math
import os
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import BasePredictionWriter
from lightning.pytorch.utilities import rank_zero_info

from voe_lightning.benchmarks.metrics import write_answer_file
from voe_lightning.data.store import write_whole


class IntPhysAnswerWriter(BasePredictionWriter):
    """Writes the IntPhys challenge's ``answer.txt`` to ``path`` at the end of ``predict``: one
        line per movie of the predict dataset (its ``names[index]``, e.g. ``O1/0001/1``) with a
        plausibility from the movie's total surprise (``benchmarks.metrics.write_answer_file``). Both writers write
    their file whole (``store.write_whole``): a full disk keeps the previous one."""

    def __init__(self, path: str | os.PathLike[str] = "answer.txt"):
        super().__init__(write_interval="epoch")
        self.path = Path(path)

    def write_on_epoch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        predictions: Sequence[Any],
        batch_indices: Sequence[Any],
    ) -> None:
        scores = gathered_scores(trainer, predictions, "surprise")
        if scores is not None:
            write_answer_file(self.path, scores)
            rank_zero_info(f"wrote {self.path} ({len(scores)} movies)")


def gathered_scores(
    trainer: L.Trainer, predictions: Sequence[Any], key: str
) -> dict[str, float] | None:
    """On rank zero, video name -> ``predictions``' ``key`` of every video of the predict
    dataset (``names[index]``), gathered from every DDP rank; None on the other ranks. A
    video scored twice or never, or two videos of one name, are refused."""
    scores = [
        (index, value)
        for batch in predictions
        for index, value in zip(batch["index"].tolist(), batch[key].tolist())
    ]
    if trainer.world_size > 1:  # each rank scored its own videos: gather them on rank 0
        gathered: list[Any] = [None] * trainer.world_size
        torch.distributed.all_gather_object(gathered, scores)
        scores = [score for rank in gathered for score in rank]
    if not trainer.is_global_zero:
        return None
    loader = trainer.predict_dataloaders
    assert loader is not None  # predict has set its dataloader
    dataset = loader.dataset
    names = dataset.names
    _check_distinct(names, getattr(dataset, "describe", lambda index: f"video {index}"))
    if sorted(index for index, _ in scores) != list(range(len(names))):
        raise RuntimeError(
            f"predict scored {len(scores)} videos ({len({i for i, _ in scores})} distinct) of "
            f"the {len(names)} in the predict dataset; every video needs exactly one score"
        )
    return {names[index]: value for index, value in sorted(scores)}


def _check_distinct(names: Sequence[str], describe: Callable[[int], str]) -> None:
    """Refuse two videos of one name (the one a score is written under), naming each video
    (``describe(index)``): keyed by name, one would overwrite the other's score."""
    found: dict[str, list[int]] = defaultdict(list)
    for index, name in enumerate(names):
        found[name].append(index)
    repeated = {name: indices for name, indices in found.items() if len(indices) > 1}
    if repeated:
        name, indices = next(iter(repeated.items()))
        raise ValueError(
            f"the predict dataset names {len(indices)} videos {name!r}: "
            f"{', '.join(describe(i) for i in indices)} ({len(repeated)} name(s) repeated); "
            "each video needs a name of its own"
        )


def intphys2_threshold(threshold: float | str) -> float:
    """The absolute threshold a number gives, or the one a ``test`` run's benchmark_metrics.json
    (IntPhys 2, e.g. on Main) learned: ``metrics.threshold.value``."""
    if not isinstance(threshold, str):
        return float(threshold)
    path = Path(threshold)
    try:
        return float(json.loads(path.read_text())["metrics"]["threshold"]["value"])
    except FileNotFoundError:
        raise FileNotFoundError(
            f"threshold file {path} does not exist; give a number or the "
            "benchmark_metrics.json of a test on IntPhys 2 Main"
        ) from None
    except (ValueError, KeyError, TypeError) as error:
        raise ValueError(
            f"{path} holds no metrics.threshold.value ({type(error).__name__}: "
            f"{error}); expected the benchmark_metrics.json of a test on IntPhys 2 "
            "Main"
        ) from None


class IntPhys2LeaderboardWriter(BasePredictionWriter):
    """Writes the IntPhys 2 leaderboard's jsonl to ``path`` at the end of ``predict``: one
    ``{"data_name", "task", "row_id", "model_answer"}`` line per video of the predict dataset,
    ``row_id`` its name and ``model_answer`` 1 (possible) when its max per-frame surprise is at
    most ``threshold``, else 0 (impossible). ``threshold`` is a number or the
    benchmark_metrics.json of a ``test`` on Main (the 90th percentile of the possible videos'
    max surprise there). ``data_name`` and ``task`` are written as given."""

    def __init__(
        self,
        threshold: float | str,
        path: str | os.PathLike[str] = "intphys2_heldout.jsonl",
        data_name: str = "IntPhys2",
        task: str = "HeldOut",
    ):
        super().__init__(write_interval="epoch")
        self.threshold = intphys2_threshold(threshold)
        self.path, self.data_name, self.task = Path(path), data_name, task

    def write_on_epoch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        predictions: Sequence[Any],
        batch_indices: Sequence[Any],
    ) -> None:
        scores = gathered_scores(trainer, predictions, "surprise_max")
        if scores is None:
            return
        bad = [name for name, value in scores.items() if not math.isfinite(value)]
        if bad:
            raise ValueError(
                f"cannot write {self.path}: {len(bad)} of {len(scores)} videos have a "
                f"non-finite surprise_max ({bad[0]!r}: {scores[bad[0]]}); a model_answer "
                "needs finite surprise, as answer.txt does"
            )
        lines = [
            json.dumps(
                {
                    "data_name": self.data_name,
                    "task": self.task,
                    "row_id": name,
                    "model_answer": int(value <= self.threshold),
                }
            )
            for name, value in scores.items()
        ]
        write_whole({self.path: "".join(line + "\n" for line in lines)})
        rank_zero_info(f"wrote {self.path} ({len(scores)} videos, threshold {self.threshold:g})")
