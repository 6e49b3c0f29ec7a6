"""An external benchmark's own published metrics and files beside a ``test`` report."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np

from voe_lightning.benchmarks.evaluation import evaluate
from voe_lightning.data.store import write_whole
from voe_lightning.probe_datamodule import probe_datamodule
from voe_lightning.report.pairs import PROBE_OUTPUT_KEYS


def write_benchmark_metrics(
    trainer: L.Trainer,
    outputs: list[dict[str, Any]],
    report_dir: Path,
    *,
    alpha: float,
    bootstrap: int,
    user: str,
) -> None:
    """External benchmarks (IntPhys, Physical Concepts, IntPhys 2) add their own published
    metrics and files (``benchmarks.evaluation``, over the DataModule's ``external_pairs``) of
    the test's probe ``outputs`` to ``report_dir``, written whole
    (``store.write_whole``); nothing for a DataModule of no external benchmark.
    ``user`` names the callback asking, should the DataModule not be a ProbeDataModule."""
    pairs = probe_datamodule(trainer, user).external_pairs()
    if pairs is None:
        return
    merged = {key: np.concatenate([output[key] for output in outputs]) for key in PROBE_OUTPUT_KEYS}
    metrics, files = evaluate(pairs, merged, alpha=alpha, bootstrap=bootstrap)
    path = report_dir / "benchmark_metrics.json"
    write_whole(
        {
            path: json.dumps(metrics, indent=2, default=lambda v: v.item()) + "\n",
            **{report_dir / name: text for name, text in files.items()},
        }
    )
    print(f"benchmark metrics written to {path}")
    for name in files:
        print(f"{name} written to {report_dir / name}")
