"""What the callbacks and the report need from a DataModule: the names that decode a probe's
``concept``/``variant`` indices and the (concept, variant) cases it tests, so a DataModule
without them is refused at once instead of being decoded with the wrong vocabulary."""

from __future__ import annotations

from abc import ABCMeta, abstractmethod
from collections.abc import Mapping
from typing import Any

import lightning as L


class ProbeDataModule(L.LightningDataModule, metaclass=ABCMeta):
    """A DataModule serving probe pairs whose ``concept``/``variant`` entries index
    ``concept_names``/``variant_names`` (subclasses set both as class attributes)."""

    @property
    @abstractmethod
    def concept_names(self) -> tuple[str, ...]:
        """Name of each ``concept`` index of this DataModule's records."""

    @property
    @abstractmethod
    def variant_names(self) -> tuple[str, ...]:
        """Name of each ``variant`` index of this DataModule's probe pairs."""

    @abstractmethod
    def probe_cases(self, split: str = "val") -> list[tuple[str, str]]:
        """The (concept, variant) pairs whose probes ``split`` holds."""

    def benchmark_metrics(
        self, outputs: Mapping[str, Any], **options: Any
    ) -> dict[str, Any] | None:
        """An external benchmark's own metrics of the merged ``probe_step`` outputs (written to
        ``benchmark_metrics.json``); None here: the package's probes have none."""
        return None

    def benchmark_files(self, outputs: Mapping[str, Any]) -> dict[str, str]:
        """Further report files of an external benchmark (file name -> text, written beside
        ``benchmark_metrics.json``) from the merged ``probe_step`` outputs; none here."""
        return {}


def probe_datamodule(trainer: L.Trainer, user: str) -> ProbeDataModule:
    """``trainer.datamodule``, refused with a clear error unless it is a ProbeDataModule;
    ``user`` names who needs it."""
    datamodule = trainer.datamodule
    if not isinstance(datamodule, ProbeDataModule):
        raise TypeError(
            f"{user} decodes probe indices with trainer.datamodule.concept_names and "
            f".variant_names, so it needs a ProbeDataModule (voe_lightning.probe_datamodule); "
            f"got {type(datamodule).__name__}")
    return datamodule
