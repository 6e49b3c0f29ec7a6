"""The object-centric model after PLATO (Piloto et al. 2022): the LightningModule (``model.py``),
object slots from the masks (``slots.py``), per-object perception (``perception.py``) and the
likelihood of the codes (``code_likelihood.py``); its slot dynamics are the shared
``voe_lightning.model.dynamics``. ``voe_lightning.model.object_centric`` was the
LightningModule's module: its names load from here."""

from voe_lightning.model.object_centric.model import (
    ARCHITECTURE,
    SURPRISES,
    ObjectCentricModel,
    build_networks,
    matching_code_size,
    parameter_count,
)

__all__ = [
    "ARCHITECTURE",
    "SURPRISES",
    "ObjectCentricModel",
    "build_networks",
    "matching_code_size",
    "parameter_count",
]
