"""The command line: ``fit``/``validate``/``test`` through LightningCLI, and ``generate``
(render the datasets), ``audit`` (physics-blind cue scores of a probe split), ``analyze``
(figures over runs) and ``intphys-answer`` (the IntPhys challenge's submission file) through
their own parsers, listed in ``--help``."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from typing import Any

import lightning as L
from lightning.pytorch.cli import LightningCLI

from voe_lightning.model import VOEModel

#: subcommand -> (module, function taking the remaining arguments, what it does for --help)
_COMMANDS_OUTSIDE_LIGHTNING = {
    "generate": ("voe_lightning.generate", "main", "render the datasets"),
    "audit": ("voe_lightning.cues", "main",
              "physics-blind cue scores of a probe split, with the model's paired statistics"),
    "analyze": ("voe_lightning.analysis", "main", "figures over runs: curves, size sweep"),
    "intphys-answer": ("datamodules.intphys", "answer_main", "the IntPhys submission file"),
}
_EPILOG = "other subcommands: " + "; ".join(
    f"{name} ({summary})" for name, (_, _, summary) in _COMMANDS_OUTSIDE_LIGHTNING.items()
) + ". Run `python -m voe_lightning SUBCOMMAND --help` for their options."


class VOECLI(LightningCLI):
    """LightningCLI that works in the run directory of ``--ckpt_path``: a resumed ``fit``
    continues its TensorBoard curves there, and ``test`` writes its report beside the
    checkpoints it evaluates. A missing checkpoint is refused before any work starts."""

    def before_instantiate_classes(self) -> None:
        config = self.config.get(self.subcommand, {})
        if config and "weights_only" in config and config.get("weights_only") is None:
            config["weights_only"] = True  # torch>=2.4 may default to unpickling anything
        ckpt_path = config.get("ckpt_path") if config else None
        if not ckpt_path or ckpt_path in ("last", "best", "hpc", "registry"):
            return
        checkpoint = Path(ckpt_path)
        if not checkpoint.is_file():
            raise FileNotFoundError(f"--ckpt_path {ckpt_path!r} does not exist")
        logger = config["trainer"].get("logger")
        run_dir = checkpoint.parent.parent  # <save_dir>/<name>/<version>/checkpoints/x.ckpt
        init_args = getattr(logger, "init_args", None)
        if (
            checkpoint.parent.name == "checkpoints"
            and init_args is not None
            and "version" in init_args
            and init_args.get("version") is None
        ):
            init_args["version"] = run_dir.name


def main(args: list[str] | None = None) -> Any:
    """Entry point of ``python -m voe_lightning``; tests call ``main([...])``."""
    words = sys.argv[1:] if args is None else list(args)
    if words and words[0] in _COMMANDS_OUTSIDE_LIGHTNING:
        module_name, function, _ = _COMMANDS_OUTSIDE_LIGHTNING[words[0]]
        return getattr(importlib.import_module(module_name), function)(words[1:])
    return VOECLI(
        model_class=VOEModel,
        datamodule_class=L.LightningDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        seed_everything_default=0,
        save_config_kwargs={"overwrite": True},
        parser_kwargs={"prog": "python -m voe_lightning", "epilog": _EPILOG},
        args=args,
    )
