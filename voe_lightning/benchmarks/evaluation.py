"""An external benchmark's own evaluation of a ``test`` run (docs/architecture.md §8): its
published metrics (``voe_lightning.benchmarks.metrics``) and extra report files, computed from the
merged ``probe_step`` outputs and what the DataModule knows of its pairs (``ExternalPairs``).

The DataModules only describe their pairs (``ProbeDataModule.external_pairs``: which benchmark,
which split, each pair's metadata, what was skipped); the evaluation is here, so
``VOEReportCallback`` writes ``benchmark_metrics.json`` and the files from ``evaluate`` without
asking the data layer to compute anything.

- IntPhys: ``metrics.grouped_metrics`` per block (and visible / occluded) over quadruplets,
  a pair's quadruplet being its ``seed`` (as in our stores; its variant names the half);
- DeepMind Physical Concepts: the same per concept;
- IntPhys 2: ``metrics.intphys2_metrics`` per principle and per principle x difficulty x
  camera, and videos.csv (one row per scored video), a pair found by its seed (its scene) and
  variant (its half).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import torch

from voe_lightning.benchmarks.external_pairs import ExternalPairs
from voe_lightning.benchmarks.intphys.reader import BLOCKS as INTPHYS_BLOCKS
from voe_lightning.benchmarks.intphys2.reader import VARIANT_NAMES as INTPHYS2_HALVES
from voe_lightning.benchmarks.metrics import (
    grouped_metrics,
    incomplete_quadruplets,
    intphys2_metrics,
    pair_surprise,
)

__all__ = [
    "BENCHMARKS",
    "VIDEO_COLUMNS",
    "evaluate",
    "external_files",
    "external_metrics",
]

#: Columns of IntPhys 2's videos.csv, one row per scored video.
VIDEO_COLUMNS = (
    "name",
    "principle",
    "difficulty",
    "camera",
    "label",
    "seed",
    "half",
    "surprise_mean",
    "surprise_max",
)


def _intphys(pairs: ExternalPairs, outputs: Mapping[str, Any], **options: Any) -> dict[str, Any]:
    """IntPhys metrics per block (``all``, and ``visible`` / ``occluded`` when scene names say);
    a movie's surprise is its sum over frames; ``options`` go to
    ``metrics.quadruplet_metrics`` (alpha, bootstrap)."""
    seeds, possible, impossible = pair_surprise(outputs)
    quadruplet = seeds
    for seed in seeds.tolist():
        if seed not in pairs.table:
            raise KeyError(f"seed {seed} names no IntPhys {pairs.split} quadruplet")
    entries = [pairs.table[q] for q in quadruplet.tolist()]
    groups = [pairs.concept_names[INTPHYS_BLOCKS.index(e["block"])] for e in entries]
    visibility = [
        e["condition"].split("_")[0] if e["condition"] != "unspecified" else None for e in entries
    ]
    return {
        "benchmark": pairs.benchmark,
        "split": pairs.split,
        "metrics": grouped_metrics(groups, quadruplet, possible, impossible, visibility, **options),
        "incomplete_quadruplets": incomplete_quadruplets(quadruplet.tolist()),
        "ambiguous_pairings": len(
            {int(q) for q, e in zip(quadruplet, entries) if e["ambiguous_pairing"]}
        ),
        "skipped": dict(pairs.skipped),
    }


def _physical_concepts(
    pairs: ExternalPairs, outputs: Mapping[str, Any], **options: Any
) -> dict[str, Any]:
    """Per concept: relative and absolute error rate and AUROC over quadruplets (IntPhys'
    definitions) and the paired t-test over matched pairs."""
    seeds, possible, impossible = pair_surprise(outputs)
    concepts = [pairs.concept_names[c] for c in torch.as_tensor(outputs["concept"]).tolist()]
    quadruplet = seeds
    return {
        "benchmark": pairs.benchmark,
        "metrics": grouped_metrics(concepts, quadruplet, possible, impossible, **options),
        "incomplete_quadruplets": incomplete_quadruplets(zip(concepts, quadruplet.tolist())),
        "skipped": dict(pairs.skipped),
    }


def _intphys2_keys(outputs: Mapping[str, Any]) -> list[tuple[int, str]]:
    """Each scored pair's (seed: its scene, half: its variant's name)."""
    return [
        (int(seed), INTPHYS2_HALVES[int(variant)])
        for seed, variant in zip(outputs["seed"], outputs["variant"])
    ]


def _intphys2_entries(pairs: ExternalPairs, outputs: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    keys = _intphys2_keys(outputs)
    unknown = [key for key in keys if key not in pairs.table]
    if unknown:
        raise KeyError(f"(seed, half) {unknown[:5]} name no IntPhys 2 {pairs.split} pair")
    return [pairs.table[key] for key in keys]


def _intphys2(pairs: ExternalPairs, outputs: Mapping[str, Any], **options: Any) -> dict[str, Any]:
    """IntPhys 2 metrics (``metrics.intphys2_metrics``: relative accuracy from mean and max
    per-frame surprise, absolute accuracy at the threshold, AUROC, the paired t-test; overall,
    per principle and per principle x difficulty x camera). ``options`` go to
    ``metrics.video_pair_metrics`` (alpha, bootstrap)."""
    entries = _intphys2_entries(pairs, outputs)
    return {
        "benchmark": pairs.benchmark,
        "split": pairs.split,
        "metrics": intphys2_metrics(
            [e["principle"] for e in entries],
            [e["difficulty"] for e in entries],
            [e["camera"] for e in entries],
            outputs["surprise_consistent"],
            outputs["surprise_inconsistent"],
            **options,
        ),
        "skipped": dict(pairs.skipped),
    }


def _intphys2_files(pairs: ExternalPairs, outputs: Mapping[str, Any]) -> dict[str, str]:
    """videos.csv: one row per scored video (``VIDEO_COLUMNS``), ``seed`` and ``half`` its
    pair's (its scene's index and standard or counterbalanced), ``label`` possible or
    impossible, surprise the mean and max over its frames."""
    text = io.StringIO()
    writer = csv.DictWriter(text, VIDEO_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for (seed, half), entry, *sides in zip(
        _intphys2_keys(outputs),
        _intphys2_entries(pairs, outputs),
        outputs["surprise_consistent"],
        outputs["surprise_inconsistent"],
    ):
        for label, frames in zip(("possible", "impossible"), sides):
            writer.writerow(
                {
                    "name": entry[label],
                    "principle": entry["principle"],
                    "difficulty": entry["difficulty"],
                    "camera": entry["camera"],
                    "label": label,
                    "seed": seed,
                    "half": half,
                    "surprise_mean": float(np.mean(frames, dtype=np.float64)),
                    "surprise_max": float(np.max(frames)),
                }
            )
    return {"videos.csv": text.getvalue()}


Metrics = Callable[..., dict[str, Any]]
Files = Callable[[ExternalPairs, Mapping[str, Any]], dict[str, str]]

#: Each external benchmark's metrics (benchmark_metrics.json) and extra files, by name.
BENCHMARKS: dict[str, tuple[Metrics, Files | None]] = {
    "IntPhys": (_intphys, None),
    "DeepMind Physical Concepts": (_physical_concepts, None),
    "IntPhys 2": (_intphys2, _intphys2_files),
}


def _evaluation(pairs: ExternalPairs) -> tuple[Metrics, Files | None]:
    if pairs.benchmark not in BENCHMARKS:
        raise ValueError(
            f"no evaluation of the external benchmark {pairs.benchmark!r}; known: "
            f"{', '.join(BENCHMARKS)}"
        )
    return BENCHMARKS[pairs.benchmark]


def external_metrics(
    pairs: ExternalPairs, outputs: Mapping[str, Any], *, alpha: float, **options: Any
) -> dict[str, Any]:
    """The benchmark's own metrics of the merged ``probe_step`` outputs (concept, seed,
    surprise_consistent, surprise_inconsistent [N, T]) at the run's ``alpha``; ``options``:
    bootstrap."""
    return _evaluation(pairs)[0](pairs, outputs, alpha=alpha, **options)


def external_files(pairs: ExternalPairs, outputs: Mapping[str, Any]) -> dict[str, str]:
    """Further report files of the benchmark (file name -> text); none for most."""
    files = _evaluation(pairs)[1]
    return {} if files is None else files(pairs, outputs)


def evaluate(
    pairs: ExternalPairs, outputs: Mapping[str, Any], *, alpha: float, **options: Any
) -> tuple[dict[str, Any], dict[str, str]]:
    """``external_metrics`` and ``external_files`` of one test run."""
    metrics = external_metrics(pairs, outputs, alpha=alpha, **options)
    return metrics, external_files(pairs, outputs)
