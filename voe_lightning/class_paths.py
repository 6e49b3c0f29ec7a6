"""Classes named by their import path, as configs and checkpoints name them
(``voe_lightning.model.VRNNLRUModel``). Importing one runs its module's code: a config or
checkpoint is code, to be run only from people you trust (as torch says of pickles)."""

from __future__ import annotations

import importlib
from typing import Any


def import_object(class_path: str) -> Any:
    """The object a dotted ``class_path`` names."""
    module_name, _, name = class_path.rpartition(".")
    return getattr(importlib.import_module(module_name), name)


def import_failure(error: Exception) -> str:
    """Why importing a class path failed, in words: a missing module's or attribute's message
    as it is; any other error (one the module raised as it was imported, an empty module name)
    with its type."""
    if isinstance(error, (ImportError, AttributeError)):
        return str(error)
    return f"{type(error).__name__}: {error}"


def missing_methods(value: Any) -> list[str]:
    """The abstract methods a class leaves unimplemented, sorted ([] for anything else)."""
    return sorted(getattr(value, "__abstractmethods__", ()) if isinstance(value, type) else ())
