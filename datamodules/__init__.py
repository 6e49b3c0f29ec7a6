"""LightningDataModules: one concept, all five interleaved, and the external benchmarks."""

from datamodules.voe import ConceptDataModule, JointDataModule, VOEDataModule

__all__ = ["ConceptDataModule", "JointDataModule", "VOEDataModule"]
