"""The command line: ``fit``/``validate``/``test``/``predict`` through LightningCLI and the
package's own subcommands (``generate``, ``audit``, ``analyze``) in the same parser, built by
jsonargparse from their functions' signatures and docstrings: one flag style, ``--config``
for every command, all listed in ``--help``."""

from __future__ import annotations

import importlib
import inspect
import pickle
import sys
from pathlib import Path
from typing import Any

import torch
import yaml
from jsonargparse import ActionConfigFile, ArgumentParser, Namespace
from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.utilities import rank_zero_warn

from voe_lightning import analysis, cues, generate, statistics
from voe_lightning.model import SurpriseModel
from voe_lightning.probe_datamodule import ProbeDataModule

#: Trainer, logger, callbacks and model class every fit/validate/test/predict starts from, so
#: ``--config configs/joint.yaml`` alone is a whole run; later ``--config`` files override it.
BASE_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "base.yaml"
#: ``--help``'s summary of Lightning's subcommands (their docstrings' first lines stop mid-sentence).
LIGHTNING_SUBCOMMANDS = {
    "fit": "Train a model, logging the VOE statistics of the validation probes.",
    "validate": "The VOE statistics of a checkpoint on the validation probes.",
    "test": "The VOE report of a checkpoint on the test probes.",
    "predict": "Per-video surprise of a checkpoint, e.g. IntPhys' answer.txt.",
}

#: The subcommands beside Lightning's: name -> the function it calls, or a dict of its own
#: subcommands (as jsonargparse's ``auto_cli`` takes them, ``_help`` being the summary).
COMMANDS: dict[str, Any] = {
    "generate": generate.generate,
    "audit": cues.audit,
    "analyze": analysis.COMMANDS,
}


class VOECLI(LightningCLI):
    """LightningCLI that works in the run directory of ``--ckpt_path``
    (``<save_dir>/<name>/<version>/checkpoints/x.ckpt``), whatever logger name the config
    gives: a resumed ``fit`` continues its TensorBoard curves and checkpoints there (warning
    that another logger name it was given is not used), and
    ``validate``/``test`` write their logs and report beside the checkpoint (an external
    benchmark's in a sub-directory named after the config's logger name, so it does not
    replace the report on the package's probes). ``validate``/``test`` save their config as
    ``<subcommand>_config.yaml``, keeping the run's training ``config.yaml``. A missing
    checkpoint is refused before any work starts, and so are a truncated or corrupt one and
    model arguments the user gives that differ from the checkpoint's (LightningCLI replaces the
    config's model arguments with the checkpoint's, so they would be ignored). The subcommands
    of ``COMMANDS`` call their function instead, with no model, data or trainer."""

    def add_arguments_to_parser(self, parser: Any) -> None:
        """The run's one significance level, ``alpha`` (configs/base.yaml sets it)."""
        parser.add_argument("--alpha", type=float, default=statistics.ALPHA,
                            help="significance level of every test, verdict and table of the "
                            "run; each callback with an alpha argument gets it")

    def _add_subcommands(self, parser: Any, **kwargs: Any) -> None:
        """Lightning's subcommands, then those of ``COMMANDS``, each listed with its summary."""
        super()._add_subcommands(parser, **kwargs)
        for action in parser._subcommands_action._choices_actions:
            action.help = LIGHTNING_SUBCOMMANDS.get(action.dest, action.help)
        for name, command in COMMANDS.items():
            _add_command(parser._subcommands_action, name, command)

    def _set_seed(self) -> None:
        if self.subcommand not in COMMANDS:  # those have no seed_everything
            super()._set_seed()

    def instantiate_classes(self) -> None:
        if self.subcommand not in COMMANDS:
            super().instantiate_classes()

    def _run_subcommand(self, subcommand: str) -> None:
        """Run the Trainer's method, or call a ``COMMANDS`` function (its return value in
        ``self.result``), printing a ValueError or OSError (a bad value) as an error, exit 2."""
        if subcommand not in COMMANDS:
            return super()._run_subcommand(subcommand)
        try:
            self.result = _call(COMMANDS[subcommand], self.config[subcommand])
        except (ValueError, OSError) as error:
            print(f"error: {error}", file=sys.stderr)
            raise SystemExit(2) from error

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
            # Without defaults, base.yaml (a default config file) is missing too, and a study
            # config's partial sections would not parse: read it first, explicitly, with the
            # checkpoint's model class (base.yaml gives a class_path only), as the run will.
            words = list(sys.argv[1:] if args is None else args)
            at = words.index(subcommand) + 1
            if trained.get("_class_path"):
                words[at:at] = ["--model", trained["_class_path"]]
            if BASE_CONFIG.is_file():
                words[at:at] = ["--config", str(BASE_CONFIG)]
            explicit = parser.parse_args(words, defaults=False)
        # Evaluating a checkpoint, its training-only arguments change nothing: no conflict.
        model_class = _import(trained["_class_path"]) if trained.get("_class_path") else None
        training_only = (model_class.TRAINING_ONLY if subcommand != "fit" and model_class
                         and issubclass(model_class, SurpriseModel) else ())
        conflicts = _conflicts(explicit[subcommand].get("model"), trained, training_only)
        if conflicts:
            raise ValueError(
                f"{ckpt_path} was trained with other model arguments than given here, and the "
                "model's arguments come from the checkpoint, so these would be ignored: "
                + "; ".join(conflicts) + ". Leave them out or give the checkpoint's values."
            )

    def before_instantiate_classes(self) -> None:
        config = self.config.get(self.subcommand, {})
        if self.subcommand in LIGHTNING_SUBCOMMANDS:
            _give_alpha(config)
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
        if self.subcommand == "fit" and init_args.get("name") not in (None, run_dir.parent.name):
            rank_zero_warn(
                f"fit --ckpt_path resumes in the checkpoint's run {run_dir}, so its curves and "
                f"checkpoints continue there; the logger name {init_args['name']!r} is not "
                "used. A later test of this run replaces its voe_report/: copy it first to keep it."
            )
        data_class = _import(config["data"].class_path) if config.get("data") else None
        # An external benchmark's DataModule has metrics of its own; ProbeDataModule's are none.
        if (self.subcommand != "fit" and data_class is not None
                and data_class.benchmark_metrics is not ProbeDataModule.benchmark_metrics):
            version = f"{version}/{init_args.get('name') or data_class.__name__}"
        elif self.subcommand != "fit" and (other := _other_data(config, run_dir)) is not None:
            version = f"{version}/{other}"
            print(f"{self.subcommand} reads {config['data'].init_args.root}, not the data "
                  f"{run_dir} was trained on: its logs and report go to {run_dir / other}, "
                  "and the run's own voe_report/ is kept")
        init_args["save_dir"] = str(run_dir.parent.parent)
        init_args["name"] = run_dir.parent.name
        init_args["version"] = version


def _give_alpha(config: Any) -> None:
    """Hand the run's ``alpha`` to every configured callback that takes one and was not given
    one; refuse a callback whose own alpha differs (one alpha per run, DESIGN.md §6)."""
    alpha = statistics.check_alpha(config["alpha"])
    for callback in config["trainer"].get("callbacks") or []:
        class_path = getattr(callback, "class_path", None)
        if class_path is None:
            continue
        if "alpha" not in inspect.signature(_import(class_path).__init__).parameters:
            continue
        if callback.get("init_args") is None:
            callback["init_args"] = Namespace()
        given = callback["init_args"].get("alpha")
        if given is None:
            callback["init_args"]["alpha"] = alpha
        elif given != alpha:
            raise ValueError(
                f"{class_path} was given alpha {given}, the run's alpha is {alpha}: a run has one "
                "significance level. Set it once, as the top-level `alpha:` of a config (e.g. "
                "configs/base.yaml) or --alpha, and leave the callbacks' alpha out."
            )


def _other_data(config: Any, run_dir: Path) -> str | None:
    """When ``config`` evaluates data under another root than the run's training config
    (``run_dir/config.yaml``) names, a folder name for its results ("data_<root>"), so that a
    mistyped or different root never replaces the run's own report; else None."""
    root = getattr(config["data"], "init_args", {}).get("root") if config.get("data") else None
    try:
        trained = yaml.safe_load((run_dir / "config.yaml").read_text())["data"]["init_args"]["root"]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return None
    if root is None or trained is None or Path(root).resolve() == Path(trained).resolve():
        return None
    return "data_" + "_".join(part for part in Path(root).parts if part not in ("/", "..", "."))


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


def _conflicts(given: Any, trained: dict, ignored: tuple[str, ...] = ()) -> list[str]:
    """'name: config X, checkpoint Y' for each model argument in ``given`` (the explicitly
    given model section), except those ``ignored``, that the checkpoint's hyperparameters
    ``trained`` hold otherwise."""
    if not isinstance(given, Namespace) or not trained:
        return []
    arguments = given.get("init_args")
    arguments = arguments.as_dict() if isinstance(arguments, Namespace) else {}
    conflicts = [
        f"{name}: config {value!r}, checkpoint {trained[name]!r}"
        for name, value in arguments.items()
        if name in trained and name not in ignored and _plain(value) != _plain(trained[name])
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


def _add_command(subcommands: Any, name: str, command: Any) -> None:
    """Add a ``COMMANDS`` entry as subcommand ``name``: its flags from the function's signature
    with their help from its docstring's Args, or a dict's functions as its own subcommands."""
    nested = isinstance(command, dict)
    description = command["_help"] if nested else inspect.getdoc(command).split("\n\nArgs:")[0]
    parser = ArgumentParser(description=description)
    parser.add_argument("--config", action=ActionConfigFile,
                        help="a YAML file of these arguments (see --print_config)")
    subcommands.add_subcommand(name, parser, help=description.splitlines()[0])
    if not nested:
        parser.add_function_arguments(command, as_group=False, sub_configs=True)
        if "alpha" in inspect.signature(command).parameters:
            parser.set_defaults(alpha=base_alpha())
        return
    inner = parser.add_subcommands()
    for inner_name, function in command.items():
        if inner_name != "_help":
            _add_command(inner, inner_name, function)


def base_alpha() -> float:
    """The ``alpha`` of configs/base.yaml (``statistics.ALPHA`` where the file or the key is
    missing): the default significance level of the commands beside Lightning's too."""
    try:
        alpha = yaml.safe_load(BASE_CONFIG.read_text()).get("alpha", statistics.ALPHA)
    except (OSError, AttributeError):
        return statistics.ALPHA
    try:
        return statistics.check_alpha(alpha)
    except ValueError as error:
        raise ValueError(f"{BASE_CONFIG}: {error}") from None


def _call(command: Any, arguments: Namespace) -> Any:
    """Call the function of a ``COMMANDS`` entry that its parsed ``arguments`` select."""
    arguments = arguments.clone()
    arguments.pop("config", None)
    if isinstance(command, dict):
        name = arguments.pop("subcommand")
        return _call(command[name], arguments[name])
    return command(**arguments)


def main(args: list[str] | None = None) -> Any:
    """Entry point of ``python -m voe_lightning``; tests call ``main([...])``. Returns the CLI,
    or for a subcommand of ``COMMANDS`` its function's return value."""
    cli = VOECLI(
        model_class=SurpriseModel,
        datamodule_class=ProbeDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        seed_everything_default=0,
        save_config_kwargs={"overwrite": True},
        parser_kwargs={"prog": "python -m voe_lightning",
                       "description": "Probe video models' intuitive physics by violation of "
                       "expectation: generate the data, train and test, audit cues, analyze runs.",
                       **{name: {"default_config_files": [str(BASE_CONFIG)]}
                          for name in LIGHTNING_SUBCOMMANDS}},
        args=args,
    )
    return cli.result if cli.subcommand in COMMANDS else cli
