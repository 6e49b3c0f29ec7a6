"""The positive control, an object-state learner with perfect perception: the LightningModule
(``model.py``), its run through the frames (``rollout.py``), the mixture over each object's next
state and the priors that shape it (``mixture.py``), what each object makes of the others
(``pairs.py``), the named parts of a state and the observations (``state.py``), its constructor
arguments (``arguments.py``) and the 3D geometry of boxes, sight lines and the floor
(``geometry.py``). ``voe_lightning.model.object_state`` was one module: its names load from
here."""

from voe_lightning.model.object_state.arguments import ARCHITECTURE, CARRIES
from voe_lightning.model.object_state.mixture import (
    LEFT_OUT,
    MAX_MOVE,
    MOVING,
    Holding,
    Mixture,
    slowed,
)
from voe_lightning.model.object_state.model import ObjectStateModel
from voe_lightning.model.object_state.pairs import PairNetwork
from voe_lightning.model.object_state.rollout import FLOOR_FEATURES
from voe_lightning.model.object_state.state import (
    BOX_CENTRE,
    BOX_HALF,
    CAMERA_XYZ,
    COLOR,
    IDENTITY,
    ORIENTATION,
    POSE,
    POSITION,
    SHAPES,
    SIZE,
    SLOT_TERMS,
    SPHERE,
    STATE_SIZE,
    Observations,
    Slots,
    observe,
    withheld_spans,
)

__all__ = [
    "ARCHITECTURE",
    "BOX_CENTRE",
    "BOX_HALF",
    "CAMERA_XYZ",
    "CARRIES",
    "COLOR",
    "FLOOR_FEATURES",
    "Holding",
    "IDENTITY",
    "LEFT_OUT",
    "MAX_MOVE",
    "MOVING",
    "Mixture",
    "ORIENTATION",
    "ObjectStateModel",
    "Observations",
    "POSE",
    "POSITION",
    "PairNetwork",
    "SHAPES",
    "SIZE",
    "SLOT_TERMS",
    "SPHERE",
    "STATE_SIZE",
    "Slots",
    "observe",
    "slowed",
    "withheld_spans",
]
