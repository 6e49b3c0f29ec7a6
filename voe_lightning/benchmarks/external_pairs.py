"""What a benchmark's DataModule tells its evaluation about the pairs it served
(``ProbeDataModule.external_pairs``): a plain record, apart from ``evaluation`` so that the
DataModules describe their pairs without importing the metrics."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class ExternalPairs:
    """What an external benchmark's evaluation needs beyond the probe outputs: ``benchmark``
    (a key of ``evaluation.BENCHMARKS``), the DataModule's ``concept_names``, the evaluated ``split``
    (None where the benchmark has one), the pairs' metadata ``table`` (IntPhys: quadruplet
    index -> {block, condition, ambiguous_pairing, ...}; IntPhys 2: (seed, half) -> {principle,
    difficulty, camera, possible, impossible, ...}; none for Physical Concepts) and the
    ``skipped`` input counts per reason."""

    benchmark: str
    concept_names: tuple[str, ...]
    split: str | None = None
    table: Mapping[Any, Mapping[str, Any]] = field(default_factory=dict)  # keyed as above
    skipped: Mapping[str, int] = field(default_factory=dict)
