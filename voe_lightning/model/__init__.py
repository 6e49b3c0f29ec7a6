"""The video models behind one protocol (``SurpriseModel``): the VRNN-LRU (``VRNNLRUModel``,
paper §4: LRU memory, encoder/decoder, recurrent core) and the object-centric model after PLATO (Piloto et al. 2022:
object slots from masks, per-object perception, interaction-network slot dynamics)
and the positive control with perfect perception (``ObjectStateModel``: object states in, slot
dynamics, the likelihood of what is seen as surprise), and the physics-blind cues as
parameter-free models (``CueScorer``; ``ObjectFollower``, rules with no dynamics over per-object
inputs), any callable frames -> surprise (``CallableModel``) and a
maintained library's predictive models (``VideoMAEScorer``, transformers' VideoMAE;
``VJEPA2Scorer``, V-JEPA 2 scored as the V-JEPA intuitive-physics evaluation scores it).
Each family is a sub-package (``vrnn_lru/``, ``object_centric/``, ``object_state/``,
``scorers/``) over the modules here that more than one uses."""

from voe_lightning.model.base import SurpriseModel
from voe_lightning.model.object_centric import ObjectCentricModel
from voe_lightning.model.object_state import ObjectStateModel
from voe_lightning.model.scorers import (
    CallableModel,
    CueScorer,
    ObjectFollower,
    VideoMAEScorer,
    VJEPA2Scorer,
)
from voe_lightning.model.vrnn_lru import VRNNLRUModel
from voe_lightning.model.vrnn_lru.memory import LRUMemory, MemoryState, Read
from voe_lightning.model.vrnn_lru.networks import Decoder, Encoder
from voe_lightning.model.vrnn_lru.vrnn import VRNNCore, VRNNOutput, gaussian_kl, standard_normal_kl

__all__ = [
    "SurpriseModel",
    "CueScorer",
    "ObjectFollower",
    "CallableModel",
    "VideoMAEScorer",
    "VJEPA2Scorer",
    "VRNNLRUModel",
    "ObjectCentricModel",
    "ObjectStateModel",
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
