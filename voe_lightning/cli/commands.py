"""The subcommands in the one parser: Lightning's, with a summary of their own, and the package's
(``COMMANDS``), each built from its function's signature and docstring and run by calling it."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

from jsonargparse import (  # type: ignore[attr-defined]  # ActionConfigFile: not in its __all__
    ActionConfigFile,
    ActionSubCommands,
    ArgumentParser,
    Namespace,
)
from lightning.pytorch.cli import LightningArgumentParser

from voe_lightning import migration
from voe_lightning.analysis import (
    comparison,
    emergence,
    latent_code,
    null,
    size_sweep,
    training_curves,
)
from voe_lightning.audit import calibration, cue_report
from voe_lightning.class_paths import import_object
from voe_lightning.cli.parser_errors import OneLineErrors
from voe_lightning.data import generate
from voe_lightning.export import command as export_command
from voe_lightning.model import causality
from voe_lightning.runs import base_alpha

#: ``--help``'s summary of Lightning's subcommands (their docstrings' first lines stop mid-sentence).
LIGHTNING_SUBCOMMANDS = {
    "fit": "Train a model, logging the VOE statistics of the validation probes.",
    "validate": "The VOE statistics of a checkpoint on the validation probes.",
    "test": "The VOE report of a checkpoint on the test probes.",
    "predict": "Per-video surprise of a checkpoint, e.g. IntPhys' answer.txt.",
}

#: The subcommands beside Lightning's: name -> its function, or a dict of subcommands (+ ``_help``).
COMMANDS: dict[str, Any] = {
    "generate": generate.generate,
    "audit": cue_report.audit,
    "check-causality": causality.check_causality,
    "analyze": {
        "_help": "Figures and tables over runs: curves, emergence, sweep, sweep-plot, compare, "
        "context-sweep, latents; untrained initializations of a config: null; and "
        "the verdict's calibration on a store: calibrate.",
        "curves": training_curves.curves,
        "emergence": emergence.emergence,
        "sweep": size_sweep.sweep,
        "sweep-plot": size_sweep.sweep_plot,
        "compare": comparison.compare,
        "context-sweep": comparison.context_sweep_table,
        "latents": latent_code.latents,
        "null": null.untrained_null,
        "calibrate": calibration.calibrate_store,
    },
    "migrate": migration.migrate,
    "export": export_command.export,
}
#: What each command leaves when Ctrl-C stops it, said in its one line (with no traceback).
INTERRUPTED = {
    "generate": "the shards it finished are kept (a shard being written is left out whole); "
    "run the same command again to resume",
    "audit": "nothing written (the cue report is written when the audit ends)",
    "check-causality": "nothing written and no verdict (it writes nothing)",
    "analyze": "its tables and figures are written when it ends, so none were (the runs a "
    "sweep finished are kept); run the same command again",
    "migrate": "each file it rewrote is whole, its original kept as <name>.before-migrate; "
    "run it again for the rest",
    "export": "nothing written to --out (the partial export is removed)",
}
#: The commands whose required arguments are positional (``migrate PATH``).
POSITIONAL = {"migrate"}


class Subcommands(ActionSubCommands):
    """jsonargparse's subcommands, Lightning's listed with their ``LIGHTNING_SUBCOMMANDS`` help."""

    def add_subcommand(self, name: str, parser: ArgumentParser, **kwargs: Any) -> ArgumentParser:
        """Add subcommand ``name``, a Lightning one with its summary as its help."""
        if name in LIGHTNING_SUBCOMMANDS:
            kwargs["help"] = LIGHTNING_SUBCOMMANDS[name]
        return super().add_subcommand(name, parser, **kwargs)


class SubcommandsParser(OneLineErrors, LightningArgumentParser):
    """LightningArgumentParser whose subcommands are ``Subcommands``, kept as ``subcommands``
    for ``add_commands``; a refusal is one line (``parser_errors.OneLineErrors``)."""

    def add_subcommands(self, *args: Any, **kwargs: Any) -> ActionSubCommands:
        """Lightning's subcommands, as ``Subcommands``, kept as ``self.subcommands``."""
        kwargs.setdefault("action", Subcommands)
        self.subcommands = super().add_subcommands(*args, **kwargs)
        return self.subcommands


class CommandParser(OneLineErrors, ArgumentParser):
    """The parser of a ``COMMANDS`` subcommand: it reports its own type errors, in one line."""


def add_commands(subcommands: ActionSubCommands, entries: dict[str, Any]) -> None:
    """Add each entry of ``entries`` (``COMMANDS``, after Lightning's) as a subcommand: its flags
    from its function's signature and docstring, or a dict's functions as its own subcommands."""
    for name, command in entries.items():
        if name == "_help":
            continue
        nested = isinstance(command, dict)
        description = (
            command["_help"] if nested else (inspect.getdoc(command) or "").split("\n\nArgs:")[0]
        )
        parser = CommandParser(description=description)
        parser.add_argument(
            "--config",
            action=ActionConfigFile,
            help="a YAML file of these arguments (see --print_config)",
        )
        subcommands.add_subcommand(name, parser, help=description.splitlines()[0])
        if nested:
            add_commands(parser.add_subcommands(), command)
            continue
        parser.add_function_arguments(
            command, as_group=False, as_positional=name in POSITIONAL, sub_configs=True
        )
        if "alpha" in inspect.signature(command).parameters:
            parser.set_defaults(alpha=base_alpha())


def call(command: Any, arguments: Namespace, entry_points: dict[str, Callable[..., Any]]) -> Any:
    """Call the function of a ``COMMANDS`` entry that its parsed ``arguments`` select, with those
    of ``entry_points`` (``_cli_main``, ``_build_cli``) its signature asks for."""
    arguments = arguments.clone()
    arguments.pop("config", None)
    if isinstance(command, dict):
        name = arguments.pop("subcommand")
        return call(command[name], arguments[name], entry_points)
    parameters = inspect.signature(command).parameters
    return command(
        **{name: _built(value) for name, value in vars(arguments).items()},
        **{key: value for key, value in entry_points.items() if key in parameters},
    )


def _built(value: Any) -> Any:
    """A parsed ``class_path``/``init_args`` value (``check-causality --model``) as its object."""
    if not (isinstance(value, Namespace) and "class_path" in value):
        return value
    init_args = value.get("init_args")
    return import_object(value["class_path"])(**(init_args.as_dict() if init_args else {}))
