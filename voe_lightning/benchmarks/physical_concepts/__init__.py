"""DeepMind Physical Concepts (Piloto et al. 2022): its TFRecords read as our records, without
TensorFlow (``reader``), and served to a Trainer (``datamodule``)."""

from voe_lightning.benchmarks.physical_concepts.datamodule import PhysicalConceptsDataModule

__all__ = ["PhysicalConceptsDataModule"]
