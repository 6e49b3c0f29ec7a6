"""The VRNN-LRU's old module path, kept only so that code and saved LightningCLI configs naming
``voe_lightning.model.module.VOEModel`` keep working: the model is
:class:`voe_lightning.model.vrnn_lru.VRNNLRUModel` (``VOEModel`` is its old name)."""

from voe_lightning.model.vrnn_lru import VOEModel, VRNNLRUModel, bf16_is_fast

__all__ = ["VOEModel", "VRNNLRUModel", "bf16_is_fast"]
