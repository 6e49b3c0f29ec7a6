"""LightningDataModules: concepts interleaved (all five by default) or one, and the external
benchmarks."""

from datamodules.intphys import IntPhysDataModule
from datamodules.intphys2 import IntPhys2DataModule
from datamodules.physical_concepts import PhysicalConceptsDataModule
from datamodules.voe import ConceptDataModule, VOEDataModule

__all__ = [
    "ConceptDataModule",
    "IntPhysDataModule",
    "IntPhys2DataModule",
    "PhysicalConceptsDataModule",
    "VOEDataModule",
]
