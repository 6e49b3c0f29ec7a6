"""LightningDataModules: one concept, all five interleaved, and the external benchmarks."""

from datamodules.intphys import IntPhysDataModule
from datamodules.physical_concepts import PhysicalConceptsDataModule
from datamodules.voe import ConceptDataModule, JointDataModule, VOEDataModule

__all__ = [
    "ConceptDataModule",
    "IntPhysDataModule",
    "JointDataModule",
    "PhysicalConceptsDataModule",
    "VOEDataModule",
]
