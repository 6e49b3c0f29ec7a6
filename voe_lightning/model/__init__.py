"""The VRNN-LRU video model (paper §4): LRU memory, encoder/decoder, recurrent core, and the
LightningModule that trains it and measures surprise."""

from voe_lightning.model.memory import LRUMemory, MemoryState, Read
from voe_lightning.model.module import VOEModel
from voe_lightning.model.networks import Decoder, Encoder
from voe_lightning.model.vrnn import VRNNCore, VRNNOutput, gaussian_kl, standard_normal_kl

__all__ = [
    "VOEModel",
    "LRUMemory",
    "MemoryState",
    "Read",
    "Encoder",
    "Decoder",
    "VRNNCore",
    "VRNNOutput",
    "gaussian_kl",
    "standard_normal_kl",
]
