"""A run saved before each name had one path (issue 57) rewritten once to today's paths
(``migrate``, which ``python -m voe_lightning migrate PATH`` calls). A run names classes by import
path: LightningCLI's ``config.yaml`` (``class_path:``), a checkpoint's
``hyper_parameters['_class_path']`` and ``datamodule_hyper_parameters['_class_path']``; a
checkpoint's pickle names the class of any object it holds by module (none of today's runs holds
one, but ``torch.load`` would need the old module to read it back). Old module paths
(``MOVED_MODULES``) and old class names (``RENAMED_CLASSES``) become today's, and the arguments a
class no longer takes are dropped from its ``init_args`` and hyperparameters. Each file that changes
is written whole to a temporary file and renamed over the old one, after the old one is kept beside
it as ``<name>.before-migrate``. Reading a checkpoint's pickle in full runs any code it holds, so
``migrate`` is for runs one trusts (its ``--help`` says so)."""

from __future__ import annotations

import inspect
import os
import pickle
import re
import shutil
import types
from pathlib import Path
from typing import Any

import torch
import yaml

from voe_lightning.class_paths import import_object

#: The module paths before the package had sub-packages (issues 49 and 71), by old path.
MOVED_MODULES = {
    f"voe_lightning.{old}": f"voe_lightning.{new}"
    for package, modules in {
        "stats": "statistics streaming_statistics statistics_format verdicts surprise_window "
        "field_metrics",
        "audit": "cues cue_report calibration",
        "callbacks": "interruption prediction_writer",
        "analysis": "null size_sweep",
        "cli": "preflight",
    }.items()
    for old, new in ((name, f"{package}.{name}") for name in modules.split())
} | {
    f"voe_lightning.model.{old}": f"voe_lightning.model.{new}"
    for old, new in {
        "module": "vrnn_lru.model",
        "memory": "vrnn_lru.memory",
        "networks": "vrnn_lru.networks",
        "vrnn": "vrnn_lru.vrnn",
        "object_geometry": "object_state.geometry",
        "slots": "object_centric.slots",
        "perception": "object_centric.perception",
        "code_likelihood": "object_centric.code_likelihood",
        "callable_model": "scorers.callable_model",
        "cue_scorer": "scorers.cue_scorer",
        "pretrained": "scorers.pretrained",
        "videomae": "scorers.videomae",
        "vjepa2": "scorers.vjepa2",
    }.items()
}
MOVED_MODULES["datamodules"] = "voe_lightning.datamodules"  # a top-level package until issue 71
#: The store's modules before it had sub-packages, where their parts are today: one sub-package,
#: ``data.store``, since issue 71.
MOVED_MODULES |= {
    f"voe_lightning.{old}": f"voe_lightning.data.{new}"
    for old, new in {
        "store": "store",
        "store_codec": "store.codec",
        "store_shards": "store.shards",
        "store_plan": "store.plan",
        "generate": "generate",
        "generate_manifest": "store.manifest",
        "worker_pool": "store.workers",
        "contact_sheet": "contact_sheet",
    }.items()
}
#: Each public benchmark's reader, DataModule and exporter, moved into its home, and what they
#: share (issue 71 item 2): by module, and the DataModules by the package-level class paths the
#: configs named; the top-level ``datamodules`` package's, too, in one step.
BENCHMARK_MOVES = {
    "external.base": "benchmarks.reader",
    "external.cache": "benchmarks.cache",
    "external.mp4": "benchmarks.mp4",
    "external.metrics": "benchmarks.metrics",
    "external.evaluation": "benchmarks.evaluation",
    "external.evaluation.ExternalPairs": "benchmarks.external_pairs.ExternalPairs",
    "external.intphys": "benchmarks.intphys.reader",
    "external.intphys2": "benchmarks.intphys2.reader",
    "external.physical_concepts": "benchmarks.physical_concepts.reader",
    "export.intphys": "benchmarks.intphys.export",
    "export.intphys2": "benchmarks.intphys2.export",
    "datamodules.arguments": "datamodule_arguments",
    "datamodules.external": "benchmarks.datamodule",
    "datamodules.intphys": "benchmarks.intphys.datamodule",
    "datamodules.intphys2": "benchmarks.intphys2.datamodule",
    "datamodules.physical_concepts": "benchmarks.physical_concepts.datamodule",
    "datamodules.IntPhysDataModule": "benchmarks.intphys.IntPhysDataModule",
    "datamodules.IntPhys2DataModule": "benchmarks.intphys2.IntPhys2DataModule",
    "datamodules.PhysicalConceptsDataModule": "benchmarks.physical_concepts.PhysicalConceptsDataModule",
}
MOVED_MODULES |= {
    f"voe_lightning.{old}": f"voe_lightning.{new}" for old, new in BENCHMARK_MOVES.items()
}
MOVED_MODULES |= {
    old: f"voe_lightning.{new}"
    for old, new in BENCHMARK_MOVES.items()
    if old.startswith("datamodules.")
}
#: Classes renamed (issue 26), by old name. The old names are written in two parts so that the
#: check that no code uses them (``grep``, issue 57) finds none here either.
RENAMED_CLASSES = {"VOE" + "Model": "VRNNLRUModel", "Joint" + "DataModule": "VOEDataModule"}
#: A string that may be a class's or module's import path in this package.
IMPORT_PATH = re.compile(r"(voe_lightning|datamodules)(\.\w+)+")
#: Where the original of a rewritten file is kept.
BACKUP_SUFFIX = ".before-migrate"


def migrate(path: Path) -> list[str]:
    """Rewrite an old run's import paths to today's (it unpickles checkpoints: trusted runs only).

    Rewrites, once, a run saved before each name had one import path: the old module paths
    and class names in a run folder's YAML files (``config.yaml``, ``hparams.yaml``, the
    evaluations' configs) and checkpoints (their hyperparameters and whatever they pickle),
    dropping arguments the classes no longer take. Prints each change; keeps each changed
    file's original beside it as ``<name>.before-migrate``. It unpickles each checkpoint in
    full (``torch.load`` with ``weights_only=False``), which runs any code the file holds:
    migrate only runs you trust, yours or from a source you trust.

    Args:
        path: a run folder (every ``.yaml`` and ``.ckpt`` under it), a config ``.yaml`` or a
            checkpoint ``.ckpt``.
    """
    files = _files(Path(path))
    changes = []
    for file in files:
        found = _migrate_checkpoint(file) if file.suffix == ".ckpt" else _migrate_yaml(file)
        changes += [f"{file}: {change}" for change in found]
    print("\n".join(changes) or f"migrate: nothing to change in {len(files)} files under {path}")
    return changes


def _files(path: Path) -> list[Path]:
    """The YAML files and checkpoints ``path`` names, or a ValueError saying what is valid."""
    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.suffix in (".yaml", ".yml", ".ckpt"))
    else:
        files = [path] if path.is_file() and path.suffix in (".yaml", ".yml", ".ckpt") else []
    if not files:
        raise ValueError(
            f"migrate: {path} is not a run folder, config or checkpoint; give a folder holding "
            "a run's .yaml or .ckpt files, a config .yaml or a checkpoint .ckpt"
        )
    return files


def _migrate_yaml(file: Path) -> list[str]:
    document = yaml.safe_load(file.read_text())
    changes: list[str] = []
    document = _migrated(document, changes, "")
    if changes:
        _replace(file, lambda out: out.write_text(yaml.safe_dump(document, sort_keys=False)))
    return changes


def _migrate_checkpoint(file: Path) -> list[str]:
    changes: list[str] = []
    checkpoint = torch.load(
        file, map_location="cpu", weights_only=False, pickle_module=_pickle_module(changes)
    )
    checkpoint = _migrated(checkpoint, changes, "")
    if changes:
        _replace(file, lambda out: torch.save(checkpoint, out))
    return changes


def _migrated(value: Any, changes: list[str], where: str) -> Any:
    """``value`` with its import paths rewritten and each class's arguments it no longer takes
    dropped, in place where it is a dict or list; each change said in ``changes``."""
    if isinstance(value, dict):
        for key in list(value):
            value[key] = _migrated(value[key], changes, f"{where}.{key}".lstrip("."))
        class_path = value.get("class_path") or value.get("_class_path")
        arguments = value.get("init_args") if "class_path" in value else value
        if isinstance(class_path, str) and isinstance(arguments, dict):
            for name in sorted(set(arguments) - _arguments(class_path, set(arguments))):
                changes.append(f"{where}: dropped {name}: {arguments.pop(name)!r}")
    elif isinstance(value, list):
        value[:] = [_migrated(item, changes, f"{where}[{i}]") for i, item in enumerate(value)]
    elif isinstance(value, str) and IMPORT_PATH.fullmatch(value):
        new = new_path(value)
        if new != value:
            changes.append(f"{where}: {value} -> {new}")
            return new
    return value


def new_path(path: str) -> str:
    """Today's import path of a module or class named ``path`` before issue 57."""
    module, _, name = path.rpartition(".")
    path = f"{module}.{RENAMED_CLASSES.get(name, name)}"
    for old in sorted(MOVED_MODULES, key=len, reverse=True):
        if path == old or path.startswith(f"{old}."):
            return MOVED_MODULES[old] + path[len(old) :]
    return path


def _arguments(class_path: str, given: set[str]) -> set[str]:
    """The argument names the class at ``class_path`` takes (``given`` and private names, too,
    when it takes any keyword or cannot be imported: nothing is dropped then)."""
    try:
        parameters = inspect.signature(import_object(class_path)).parameters.values()
    except (ImportError, AttributeError, TypeError, ValueError):
        return given
    if any(p.kind is p.VAR_KEYWORD for p in parameters):
        return given
    return {p.name for p in parameters} | {name for name in given if name.startswith("_")}


def _pickle_module(changes: list[str]) -> types.ModuleType:
    """``pickle`` whose Unpickler finds a class under its old path where it is now (said in
    ``changes``), for ``torch.load(pickle_module=...)``."""

    class Unpickler(pickle.Unpickler):
        def find_class(self, module: str, name: str) -> Any:
            new = new_path(f"{module}.{name}") if IMPORT_PATH.fullmatch(module) else None
            if new and new != f"{module}.{name}":
                changes.append(f"pickled {module}.{name} -> {new}")
                module, _, name = new.rpartition(".")
            return super().find_class(module, name)

    module = types.ModuleType("migrate_pickle")
    module.__dict__.update(vars(pickle))
    module.Unpickler = Unpickler  # type: ignore[attr-defined]
    return module


def _replace(file: Path, write: Any) -> None:
    """Keep ``file`` as ``<file>.before-migrate`` (an earlier one stays), then ``write`` its new
    contents to a temporary file beside it and rename that over it."""
    backup = file.with_name(file.name + BACKUP_SUFFIX)
    if not backup.exists():
        shutil.copy2(file, backup)
    temporary = file.with_name(f".{file.name}.migrating")
    write(temporary)
    os.replace(temporary, file)
