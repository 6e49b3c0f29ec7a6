"""The object-state learner (the positive control and the learned result): the LightningModule
(``model.py``), its run through the frames (``rollout.py``), what it reads of a video's masks
and frames without 3D states (``masks.py``) and with the depth image's measures (``rgbd.py``), the
learned code of each object's pixels
(``pixels.py``), the mixture over each object's next
state and the priors that shape it (``mixture.py``), what each object makes of the others
(``pairs.py``), the named parts of a state and the observations (``state.py``), its constructor
arguments (``arguments.py``) and the 3D geometry of boxes, sight lines and the floor
(``geometry.py``)."""

from voe_lightning.model.object_state.model import ObjectStateModel

__all__ = ["ObjectStateModel"]
