"""The object-centric model after PLATO (Piloto et al. 2022): the LightningModule (``model.py``),
object slots from the masks (``slots.py``), per-object perception (``perception.py``) and the
likelihood of the codes (``code_likelihood.py``); its slot dynamics are the shared
``voe_lightning.model.dynamics``."""

from voe_lightning.model.object_centric.model import ObjectCentricModel

__all__ = ["ObjectCentricModel"]
