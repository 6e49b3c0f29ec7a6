"""The paper's VRNN with LRU memory (paper §4): the LightningModule (``model.py``), its recurrent
core (``vrnn.py``), the LRU memory (``memory.py``) and the convolutional encoder and decoder
(``networks.py``). ``voe_lightning.model.vrnn_lru`` was the LightningModule's module: its names
load from here."""

from voe_lightning.model.vrnn_lru.model import (
    ARCHITECTURE,
    COMPILE_MODES,
    LOSS_TERMS,
    PRECISIONS,
    VOEModel,
    VRNNLRUModel,
    bf16_is_fast,
)

__all__ = [
    "ARCHITECTURE",
    "COMPILE_MODES",
    "LOSS_TERMS",
    "PRECISIONS",
    "VOEModel",
    "VRNNLRUModel",
    "bf16_is_fast",
]
