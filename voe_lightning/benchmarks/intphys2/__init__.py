"""IntPhys 2 (Bordes et al. 2025): its released layout read as our records (``reader``, with
``voe_lightning.benchmarks.mp4``), served to a Trainer (``datamodule``), and our probes written
in its layout (``export``)."""

from voe_lightning.benchmarks.intphys2.datamodule import IntPhys2DataModule
from voe_lightning.benchmarks.intphys2.export import write_intphys2

__all__ = ["IntPhys2DataModule", "write_intphys2"]
