"""Classes named by their import path, as configs and checkpoints name them
(``voe_lightning.model.VRNNLRUModel``)."""

from __future__ import annotations

import importlib
from typing import Any


def import_object(class_path: str) -> Any:
    """The object a dotted ``class_path`` names."""
    module_name, _, name = class_path.rpartition(".")
    return getattr(importlib.import_module(module_name), name)
