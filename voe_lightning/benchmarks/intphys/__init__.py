"""IntPhys (Riochet et al. 2018): its released layout read as our records (``reader``), served
to a Trainer (``datamodule``), and our probes written in its labelled dev layout (``export``)."""

from voe_lightning.benchmarks.intphys.datamodule import IntPhysDataModule
from voe_lightning.benchmarks.intphys.export import write_intphys

__all__ = ["IntPhysDataModule", "write_intphys"]
