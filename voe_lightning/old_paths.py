"""The modules' paths before the package had sub-packages (issue 49), kept loading: saved
LightningCLI configs and checkpoints name classes by module path
(``voe_lightning.prediction_writer.IntPhysAnswerWriter``), and other people's code imports
``voe_lightning.statistics``. Each old path in ``OLD_PATHS`` imports as the very module at its
new path (the same objects, so a monkeypatch of either is one patch), without a file of its
own at the package root; the package's own modules import only the new paths
(``tests/test_imports.py``)."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
from types import ModuleType

#: Old module path -> the module it is now.
OLD_PATHS = {
    f"voe_lightning.{old}": f"voe_lightning.{new}"
    for old, new in {
        "store": "data.store",
        "store_codec": "data.store_codec",
        "store_shards": "data.store_shards",
        "store_plan": "data.store_plan",
        "generate": "data.generate",
        "generate_manifest": "data.generate_manifest",
        "worker_pool": "data.worker_pool",
        "contact_sheet": "data.contact_sheet",
        "statistics": "stats.statistics",
        "streaming_statistics": "stats.streaming_statistics",
        "statistics_format": "stats.statistics_format",
        "verdicts": "stats.verdicts",
        "surprise_window": "stats.surprise_window",
        "field_metrics": "stats.field_metrics",
        "cues": "audit.cues",
        "cue_report": "audit.cue_report",
        "calibration": "audit.calibration",
        "interruption": "callbacks.interruption",
        "prediction_writer": "callbacks.prediction_writer",
        "analysis": "cli.analysis",
        "null": "cli.null",
        "size_sweep": "cli.size_sweep",
        "preflight": "cli.preflight",
        "model.module": "model.vrnn_lru.model",
        "model.memory": "model.vrnn_lru.memory",
        "model.networks": "model.vrnn_lru.networks",
        "model.vrnn": "model.vrnn_lru.vrnn",
        "model.object_geometry": "model.object_state.geometry",
        "model.slots": "model.object_centric.slots",
        "model.perception": "model.object_centric.perception",
        "model.code_likelihood": "model.object_centric.code_likelihood",
        "model.callable_model": "model.scorers.callable_model",
        "model.cue_scorer": "model.scorers.cue_scorer",
        "model.pretrained": "model.scorers.pretrained",
        "model.videomae": "model.scorers.videomae",
        "model.vjepa2": "model.scorers.vjepa2",
    }.items()
}


class OldPathFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds an old path of ``OLD_PATHS`` and loads it as the module at its new path."""

    def find_spec(
        self, name: str, path: object = None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        return importlib.util.spec_from_loader(name, self) if name in OLD_PATHS else None

    def __init__(self) -> None:
        self.specs: dict[str, importlib.machinery.ModuleSpec] = {}  # new path -> its own spec

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        module = importlib.import_module(OLD_PATHS[spec.name])
        self.specs[module.__name__] = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run, the module at the new path has run already; only its ``__spec__``,
        which the import system has just set to the old path's, is put back."""
        module.__spec__ = self.specs[module.__name__]


def install() -> None:
    """Puts the finder first on ``sys.meta_path``, once: first, because an editable install of
    another checkout (its finder maps ``voe_lightning.*`` to that checkout's files) would
    otherwise load that checkout's old flat module."""
    if not any(isinstance(finder, OldPathFinder) for finder in sys.meta_path):
        sys.meta_path.insert(0, OldPathFinder())
