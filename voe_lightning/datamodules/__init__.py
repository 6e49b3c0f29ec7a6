"""LightningDataModules of our own stores: concepts interleaved (all five by default) or one.
The public benchmarks' DataModules are in ``voe_lightning.benchmarks``, each in its home."""

from voe_lightning.datamodules.voe import ConceptDataModule, VOEDataModule

__all__ = ["ConceptDataModule", "VOEDataModule"]
