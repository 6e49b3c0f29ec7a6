"""Models with nothing to train: the physics-blind cues (``cue_scorer.py``) and followers of
per-object inputs (``followers.py``), any callable frames -> surprise (``callable_model.py``) and
the maintained libraries' pretrained predictive models (``pretrained.py``: what they share;
``videomae.py``, ``vjepa2.py``)."""

from voe_lightning.model.scorers.callable_model import CallableModel
from voe_lightning.model.scorers.cue_scorer import CueScorer
from voe_lightning.model.scorers.followers import ObjectFollower
from voe_lightning.model.scorers.pretrained import PretrainedScorer
from voe_lightning.model.scorers.videomae import VideoMAEScorer
from voe_lightning.model.scorers.vjepa2 import VJEPA2Scorer

__all__ = [
    "CallableModel",
    "CueScorer",
    "ObjectFollower",
    "PretrainedScorer",
    "VideoMAEScorer",
    "VJEPA2Scorer",
]
