"""What the callbacks and the report need from a DataModule: the names that decode a probe's
``concept``/``variant`` indices and the (concept, variant) cases it tests, so a DataModule
without them is refused at once instead of being decoded with the wrong vocabulary."""

from __future__ import annotations

from abc import ABCMeta, abstractmethod
from typing import TYPE_CHECKING, Any

import lightning as L

if TYPE_CHECKING:
    from voe_lightning.benchmarks.external_pairs import ExternalPairs


class ProbeDataModule(L.LightningDataModule, metaclass=ABCMeta):
    """A DataModule serving probe pairs whose ``concept``/``variant`` entries index
    ``concept_names``/``variant_names`` (subclasses set both as class attributes)."""

    #: The data's name where its videos have no object masks (their ``mask`` entries are
    #: zeros: IntPhys, IntPhys 2), so a model that needs masks is refused naming it; None
    #: where the masks are the data's own.
    without_masks: str | None = None

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

    def probe_source(self) -> dict[str, Any]:
        """Where this DataModule's probe pairs come from, for the report's ``source``: its
        data root (``hparams.root``, None where it has none); a DataModule that draws its
        probes elsewhere says where (``VOEDataModule``: its seed offset and probe store)."""
        root = getattr(self, "hparams", {}).get("root")
        return {"data_root": str(root) if root is not None else None}

    def external_pairs(self) -> ExternalPairs | None:
        """What an external benchmark's own evaluation needs of this DataModule's test pairs
        (``voe_lightning.benchmarks.evaluation``: metrics written to ``benchmark_metrics.json``,
        extra files); None here: the package's probes have none."""
        return None


def probe_datamodule(trainer: L.Trainer, user: str) -> ProbeDataModule:
    """``trainer.datamodule``, refused with a clear error unless it is a ProbeDataModule;
    ``user`` names who needs it."""
    datamodule = trainer.datamodule  # type: ignore[attr-defined]  # lightning: set by the Trainer's DataConnector, undeclared on Trainer
    if not isinstance(datamodule, ProbeDataModule):
        raise TypeError(
            f"{user} decodes probe indices with trainer.datamodule.concept_names and "
            f".variant_names, so it needs a ProbeDataModule (voe_lightning.probe_datamodule); "
            f"got {type(datamodule).__name__}"
        )
    return datamodule
