"""LightningDataModules: concepts interleaved (all five by default) or one, and the external
benchmarks. ``JointDataModule`` is ``VOEDataModule``'s old name, kept for old configs."""

from datamodules.intphys import IntPhysDataModule
from datamodules.intphys2 import IntPhys2DataModule
from datamodules.physical_concepts import PhysicalConceptsDataModule
from datamodules.voe import ConceptDataModule, JointDataModule, VOEDataModule

__all__ = [
    "ConceptDataModule",
    "IntPhysDataModule",
    "IntPhys2DataModule",
    "JointDataModule",
    "PhysicalConceptsDataModule",
    "VOEDataModule",
]
