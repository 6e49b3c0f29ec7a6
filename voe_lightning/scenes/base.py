"""The old import path of the scene toolkit, which is now one module per idea: ``camera`` (video
options, camera poses and ranges, projection), ``appearance`` (shapes, colours), ``rendering``
(the stage and the renderer), ``simulation``, ``builder``, ``sampling`` and ``recording``. Kept
only for the names code outside ``scenes/`` imports from here: ``FOVY``
(``model/object_state.py``, ``model/object_geometry.py``), ``VideoOptions`` and ``get_renderer``
(``benchmarks/generation.py``)."""

from voe_lightning.scenes.camera import FOVY, VideoOptions
from voe_lightning.scenes.rendering import get_renderer

__all__ = ["FOVY", "VideoOptions", "get_renderer"]
