"""What the callbacks share: the run's significance level, what a probe callback found
(``ProbeOutcome``), the probe DataModule's concept and variant names, and objects gathered from
every DDP rank."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L

from voe_lightning.probe_datamodule import probe_datamodule
from voe_lightning.stats.causality import Causality
from voe_lightning.stats.statistics import check_alpha


class RunAlpha:
    """A callback's ``alpha``: the run's significance level, which the CLI hands every callback
    that takes one (configs/base.yaml's ``alpha``); a callback used without it refuses to test
    rather than fall back on a default."""

    def __init__(self, alpha: float | None) -> None:
        self._alpha = None if alpha is None else check_alpha(alpha)

    @property
    def alpha(self) -> float:
        if self._alpha is None:
            raise ValueError(
                f"{type(self).__name__} was given no alpha: pass the run's significance level "
                "(alpha=0.01 is configs/base.yaml's; the CLI hands it over)"
            )
        return self._alpha


@dataclass(frozen=True)
class ProbeOutcome:
    """What a probe callback found on its last run, for the CLI: its causality check (None
    before one ran) and the report folder it wrote (None for none)."""

    causality: Causality | None
    report_dir: Path | None = None


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
