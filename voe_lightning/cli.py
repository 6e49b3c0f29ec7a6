"""The command line: ``fit``/``validate``/``test`` through LightningCLI, and ``generate``
(render the datasets), ``audit`` (physics-blind cue scores of a probe split), ``analyze``
(figures over runs) and ``intphys-answer`` (the IntPhys challenge's submission file) through
their own parsers, listed in ``--help``."""

from __future__ import annotations

import importlib
import pickle
import sys
from pathlib import Path
from typing import Any

import lightning as L
import torch
from jsonargparse import Namespace
from lightning.pytorch.cli import LightningCLI

from voe_lightning.model import SurpriseModel

#: subcommand -> (module, function taking the remaining arguments, what it does for --help)
_COMMANDS_OUTSIDE_LIGHTNING = {
    "generate": ("voe_lightning.generate", "main", "render the datasets"),
    "audit": ("voe_lightning.cues", "main",
              "physics-blind cue scores of a probe split, with the model's paired statistics"),
    "analyze": ("voe_lightning.analysis", "main", "figures over runs: curves, size sweep"),
}
_EPILOG = "other subcommands: " + "; ".join(
    f"{name} ({summary})" for name, (_, _, summary) in _COMMANDS_OUTSIDE_LIGHTNING.items()
) + ". Run `python -m voe_lightning SUBCOMMAND --help` for their options."


class VOECLI(LightningCLI):
    """LightningCLI that works in the run directory of ``--ckpt_path``
    (``<save_dir>/<name>/<version>/checkpoints/x.ckpt``), whatever logger name the config
    gives: a resumed ``fit`` continues its TensorBoard curves and checkpoints there, and
    ``validate``/``test`` write their logs and report beside the checkpoint (an external
    benchmark's in a sub-directory named after the config's logger name, so it does not
    replace the report on the package's probes). ``validate``/``test`` save their config as
    ``<subcommand>_config.yaml``, keeping the run's training ``config.yaml``. A missing
    checkpoint is refused before any work starts, and so are a truncated or corrupt one and
    model arguments the user gives that differ from the checkpoint's (LightningCLI replaces the
    config's model arguments with the checkpoint's, so they would be ignored)."""

    def parse_arguments(self, parser: Any, args: Any) -> None:
        """Parse, then read --ckpt_path (naming it if unreadable) and compare the model
        arguments given explicitly (a re-parse without defaults) with its hyperparameters."""
        super().parse_arguments(parser, args)
        subcommand = self.config.get("subcommand")
        ckpt_path = self.config[subcommand].get("ckpt_path") if subcommand else None
        if not ckpt_path or not Path(ckpt_path).is_file():
            return
        trained = read_checkpoint(ckpt_path).get("hyper_parameters") or {}
        if isinstance(args, (dict, Namespace)):
            explicit = parser.parse_object(args, defaults=False)
        else:
            explicit = parser.parse_args(args, defaults=False)
        conflicts = _conflicts(explicit[subcommand].get("model"), trained)
        if conflicts:
            raise ValueError(
                f"{ckpt_path} was trained with other model arguments than given here, and the "
                "model's arguments come from the checkpoint, so these would be ignored: "
                + "; ".join(conflicts) + ". Leave them out or give the checkpoint's values."
            )

    def before_instantiate_classes(self) -> None:
        config = self.config.get(self.subcommand, {})
        if config and "weights_only" in config and config.get("weights_only") is None:
            config["weights_only"] = True  # torch>=2.4 may default to unpickling anything
        if self.subcommand != "fit":
            self.save_config_kwargs = {**self.save_config_kwargs,
                                       "config_filename": f"{self.subcommand}_config.yaml"}
        ckpt_path = config.get("ckpt_path") if config else None
        if not ckpt_path or ckpt_path in ("last", "best", "hpc", "registry"):
            return
        checkpoint = Path(ckpt_path)
        if not checkpoint.is_file():
            raise FileNotFoundError(f"--ckpt_path {ckpt_path!r} does not exist")
        if checkpoint.parent.name == "checkpoints":
            self._log_into_run(config, run_dir=checkpoint.parent.parent)

    def _log_into_run(self, config: Any, run_dir: Path) -> None:
        """Point a logger with save_dir/name/version (TensorBoard, CSV) at ``run_dir``."""
        init_args = getattr(config["trainer"].get("logger"), "init_args", None)
        if init_args is None or not all(key in init_args for key in ("save_dir", "name", "version")):
            return
        version = run_dir.name
        data_class = _import(config["data"].class_path) if config.get("data") else None
        if self.subcommand != "fit" and hasattr(data_class, "benchmark_metrics"):
            version = f"{version}/{init_args.get('name') or data_class.__name__}"
        init_args["save_dir"] = str(run_dir.parent.parent)
        init_args["name"] = run_dir.parent.name
        init_args["version"] = version


def read_checkpoint(path: str | Path) -> dict:
    """``torch.load`` of a checkpoint (weights only), naming the file when it cannot be read
    (torch's errors for a truncated file, e.g. ``OSError: [Errno 22]``, name none)."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except PermissionError:
        raise  # names the file already
    except (OSError, EOFError, RuntimeError, pickle.UnpicklingError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(f"cannot read the checkpoint {path}: it is truncated or corrupt "
                         f"({reason})") from error


def _conflicts(given: Any, trained: dict) -> list[str]:
    """'name: config X, checkpoint Y' for each model argument in ``given`` (the explicitly
    given model section) that the checkpoint's hyperparameters ``trained`` hold otherwise."""
    if not isinstance(given, Namespace) or not trained:
        return []
    arguments = given.get("init_args")
    arguments = arguments.as_dict() if isinstance(arguments, Namespace) else {}
    conflicts = [
        f"{name}: config {value!r}, checkpoint {trained[name]!r}"
        for name, value in arguments.items()
        if name in trained and _plain(value) != _plain(trained[name])
    ]
    class_path, trained_class_path = given.get("class_path"), trained.get("_class_path")
    if class_path and trained_class_path and _import(class_path) is not _import(trained_class_path):
        conflicts.insert(0, f"class_path: config {class_path!r}, checkpoint {trained_class_path!r}")
    return conflicts


def _plain(value: Any) -> Any:
    """Tuples as lists: a parsed (32, 32) and a checkpoint's [32, 32] are the same value."""
    return [_plain(item) for item in value] if isinstance(value, (list, tuple)) else value


def _import(class_path: str) -> Any:
    """The object a dotted ``class_path`` names."""
    module_name, _, name = class_path.rpartition(".")
    return getattr(importlib.import_module(module_name), name)


def main(args: list[str] | None = None) -> Any:
    """Entry point of ``python -m voe_lightning``; tests call ``main([...])``."""
    words = sys.argv[1:] if args is None else list(args)
    if words and words[0] in _COMMANDS_OUTSIDE_LIGHTNING:
        module_name, function, _ = _COMMANDS_OUTSIDE_LIGHTNING[words[0]]
        return getattr(importlib.import_module(module_name), function)(words[1:])
    return VOECLI(
        model_class=SurpriseModel,
        datamodule_class=L.LightningDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        seed_everything_default=0,
        save_config_kwargs={"overwrite": True},
        parser_kwargs={"prog": "python -m voe_lightning", "epilog": _EPILOG},
        args=args,
    )
