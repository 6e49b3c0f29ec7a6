"""The paper's VRNN with LRU memory (paper §4): the LightningModule (``model.py``), its recurrent
core (``vrnn.py``), the LRU memory (``memory.py``) and the convolutional encoder and decoder
(``networks.py``)."""

from voe_lightning.model.vrnn_lru.model import VRNNLRUModel

__all__ = ["VRNNLRUModel"]
