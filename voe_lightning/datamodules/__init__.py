"""LightningDataModules: concepts interleaved (all five by default) or one, and the external
benchmarks."""

from voe_lightning.datamodules.intphys import IntPhysDataModule
from voe_lightning.datamodules.intphys2 import IntPhys2DataModule
from voe_lightning.datamodules.physical_concepts import PhysicalConceptsDataModule
from voe_lightning.datamodules.voe import ConceptDataModule, VOEDataModule

__all__ = [
    "ConceptDataModule",
    "IntPhysDataModule",
    "IntPhys2DataModule",
    "PhysicalConceptsDataModule",
    "VOEDataModule",
]
