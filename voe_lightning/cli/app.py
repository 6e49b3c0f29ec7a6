"""The command line: ``fit``/``validate``/``test``/``predict`` through LightningCLI and the
package's own subcommands (``generate``, ``audit``, ``analyze``) in the same parser, built by
jsonargparse from their functions' signatures and docstrings: one flag style, ``--config``
for every command, all listed in ``--help``."""

from __future__ import annotations

import builtins
import functools
import importlib
import inspect
import os
import re
import sys
import traceback
from pathlib import Path
from typing import Any, Union

import yaml
from jsonargparse import ActionConfigFile, ArgumentParser, Namespace
from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.utilities import rank_zero_warn
from lightning.pytorch.utilities.exceptions import MisconfigurationException, SIGTERMException
from lightning.pytorch.utilities.seed import isolate_rng

from voe_lightning import causality, runs
from voe_lightning.audit import cue_report
from voe_lightning.callbacks import VOEReportCallback
from voe_lightning.callbacks.interruption import InterruptCheckpoint
from voe_lightning.cli import analysis, null, preflight
from voe_lightning.data import generate
from voe_lightning.model import SurpriseModel
from voe_lightning.probe_datamodule import ProbeDataModule
from voe_lightning.report.priors_alone import PRIORS_ALONE
from voe_lightning.runs import read_checkpoint
from voe_lightning.stats import statistics
from voe_lightning.stats.surprise_window import surprise_window

#: Trainer, logger, callbacks and model class every fit/validate/test/predict starts from, so
#: ``--config configs/joint.yaml`` alone is a whole run; later ``--config`` files override it.
BASE_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "base.yaml"
#: ``--help``'s summary of Lightning's subcommands (their docstrings' first lines stop mid-sentence).
LIGHTNING_SUBCOMMANDS = {
    "fit": "Train a model, logging the VOE statistics of the validation probes.",
    "validate": "The VOE statistics of a checkpoint on the validation probes.",
    "test": "The VOE report of a checkpoint on the test probes.",
    "predict": "Per-video surprise of a checkpoint, e.g. IntPhys' answer.txt.",
}

#: Environment variable that, like ``--debug`` anywhere on the command line, shows the traceback
#: of a refused argument or input instead of its one-line error.
DEBUG_VARIABLE = "VOE_DEBUG"
#: Errors that mean a bad argument or input, or a run that cannot go on (a non-finite loss,
#: ``SurpriseModel._check_finite``): printed as one line, exit status 2.
USER_ERRORS = (ValueError, OSError, MisconfigurationException, FloatingPointError)
#: Exit status of a fit/validate/test whose probe surprise failed the causality check (the
#: report is written, without verdicts), unless ``--allow_non_causal true``.
NOT_CAUSAL_EXIT = 3

#: The subcommands beside Lightning's: name -> the function it calls, or a dict of its own
#: subcommands (as jsonargparse's ``auto_cli`` takes them, ``_help`` being the summary).
COMMANDS: dict[str, Any] = {
    "generate": generate.generate,
    "audit": cue_report.audit,
    "check-causality": causality.check_causality,
    "analyze": analysis.COMMANDS,
}


class VOECLI(LightningCLI):
    """LightningCLI that works in the run directory of ``--ckpt_path``
    (``<save_dir>/<name>/<version>/checkpoints/x.ckpt``), whatever logger name the config
    gives: a resumed ``fit`` continues its TensorBoard curves and checkpoints there (warning
    that another logger name it was given is not used), and
    ``validate``/``test`` write their logs and report beside the checkpoint: the run's own
    report for its last.ckpt on its training data and concepts, a folder of its own
    (``runs.report_folder``) for any other checkpoint, data root, concepts or external
    benchmark. ``validate``/``test`` save their config as ``<subcommand>_config.yaml``,
    keeping the run's training ``config.yaml`` and an earlier evaluation's config there
    (theirs then ``<subcommand>_config-2.yaml``, ``-3``...: ``runs.RunConfig``). A ``test``
    whose report callback asks for ``priors_alone`` first tests the config at initialization
    (``_test_priors_alone``). ``--ckpt_path last``/``best`` name the newest run of the config's
    logger name. A missing checkpoint (or a directory) is refused before
    any work starts, and so are a truncated or corrupt one, model arguments the user gives
    that differ from the checkpoint's (LightningCLI replaces the config's model arguments with
    the checkpoint's, so they would be ignored; evaluating it, the model's ``EVALUATION_ONLY``
    ones given are used instead, and its report gets a folder of its own), and
    ``test``/``predict`` of a model with trainable parameters and no checkpoint. SIGTERM or
    SIGINT during ``fit`` saves a resumable last.ckpt and exits with 128 + the signal's
    number (``interruption``). A run whose probe surprise is not causal
    (``causality.check_prefix``: it differs where a pair's videos are identical) exits with
    ``NOT_CAUSAL_EXIT`` after its report, unless ``--allow_non_causal true``. The subcommands
    of ``COMMANDS`` call their function instead, with no model, data or trainer."""

    def add_arguments_to_parser(self, parser: Any) -> None:
        """The run's one significance level, ``alpha`` (configs/base.yaml sets it), its
        ``surprise_window``, ``branch`` (a resumed fit in a new version) and
        ``allow_non_causal``."""
        parser.add_argument(
            "--alpha",
            type=float,
            default=statistics.ALPHA,
            help="significance level of every test, verdict and table of the "
            "run; each callback with an alpha argument gets it",
        )
        parser.add_argument(
            "--surprise_window",
            type=Union[str, dict, None],  # noqa: UP007 (jsonargparse's type)
            default="all",
            help="frames a video's surprise sums in the report: all (the "
            "paper's) or {start: first_difference, frames: k}, reported beside "
            "all frames; each callback with a surprise_window argument gets it",
        )
        parser.add_argument(
            "--branch",
            type=bool,
            default=False,
            help="fit --ckpt_path: continue from the checkpoint in a new version "
            "of its run's logger name (other data allowed), keeping the run",
        )
        parser.add_argument(
            "--allow_non_causal",
            type=bool,
            default=False,
            help="exit 0 though the model's surprise is not causal (it differs "
            "where a probe pair's videos are identical); verdicts stay withheld",
        )

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
        ``self.result``). A run stopped by SIGTERM/SIGINT exits with 128 + its number, saying
        where ``InterruptCheckpoint`` saved it."""
        if subcommand in COMMANDS:
            self.result = _call(COMMANDS[subcommand], self.config[subcommand])
            return
        try:
            super()._run_subcommand(subcommand)
        except SIGTERMException as stopped:
            interrupt = next(
                (
                    callback
                    for callback in self.trainer.callbacks
                    if isinstance(callback, InterruptCheckpoint)
                ),
                InterruptCheckpoint(),
            )
            saved = (
                f"saved a resumable checkpoint {interrupt.saved}: continue with "
                f"`fit --ckpt_path {interrupt.saved}`"
                if interrupt.saved
                else "nothing saved"
            )
            print(
                f"{subcommand} stopped by {interrupt.signal_name or 'SIGTERM'} at step "
                f"{self.trainer.global_step}; {saved}",
                file=sys.stderr,
            )
            raise SystemExit(interrupt.exit_code()) from stopped

    def before_fit(self) -> None:
        """Every fit saves a resumable checkpoint when preempted (SIGTERM) or interrupted."""
        callbacks = self.trainer.callbacks
        if not any(isinstance(callback, InterruptCheckpoint) for callback in callbacks):
            callbacks.append(InterruptCheckpoint())

    def before_test(self) -> None:
        self._refuse_untrained("test")
        self._test_priors_alone()

    def _test_priors_alone(self) -> None:
        """Where a ``VOEReportCallback`` asks for ``priors_alone``: the run's config as tested
        (the checkpoint's model arguments), at initialization under the run's seed, tested
        first on the same probes (``null.priors_alone``, into ``<log dir>/priors_alone/``) and
        handed to the callback for its report; this test's random state is kept as it was."""
        callbacks = [
            callback
            for callback in self.trainer.callbacks
            if isinstance(callback, VOEReportCallback) and callback.priors_alone
        ]
        if not callbacks:
            return
        config = self.config["test"]
        seed = config.get("seed_everything")
        if isinstance(seed, bool) or not isinstance(seed, int):
            raise ValueError(
                f"priors_alone tests the config at initialization under the run's "
                f"seed, and seed_everything is {seed!r}: give an integer"
            )
        saved = yaml.safe_load(self._parser("test").dump(config, skip_none=False))
        own = set(inspect.signature(self.trainer.test).parameters) - self.subcommands()["test"]
        for key in ("config", *own):  # ckpt_path, verbose...: the untrained copy has none
            saved.pop(key, None)
        out = Path(self.trainer.log_dir) / "priors_alone"
        print(
            f"test: first the config at initialization (seed {seed}) on the same probes, "
            f"its {PRIORS_ALONE} rows for the report, into {out}"
        )
        with isolate_rng():
            untrained = null.priors_alone(functools.partial(_cli, run=False), saved, seed, out)
        for callback in callbacks:
            callback.untrained = untrained

    def after_fit(self) -> None:
        self._exit_if_not_causal("fit")

    def after_validate(self) -> None:
        self._exit_if_not_causal("validate")

    def after_test(self) -> None:
        self._exit_if_not_causal("test")

    def _exit_if_not_causal(self, subcommand: str) -> None:
        """Say so in one line and exit with ``NOT_CAUSAL_EXIT`` where a callback's causality
        check failed (the report and tables give no verdict), unless ``--allow_non_causal``."""
        for callback in self.trainer.callbacks:
            causality = getattr(callback, "causality", None)
            if causality is None or causality.causal:
                continue
            where = getattr(callback, "report_dir", None)
            if self.config[subcommand].get("allow_non_causal"):
                print(f"{subcommand}: {causality.line()} (--allow_non_causal)", file=sys.stderr)
                return
            print(
                f"error: {subcommand}: {causality.line()}"
                + (f" (report: {where})" if where else "")
                + "; --allow_non_causal true exits 0 with the verdicts withheld",
                file=sys.stderr,
            )
            raise SystemExit(NOT_CAUSAL_EXIT)

    def before_predict(self) -> None:
        self._refuse_untrained("predict")

    def _refuse_untrained(self, subcommand: str) -> None:
        """A model with trainable parameters and no checkpoint would report on random weights;
        a model without (a physics-blind scorer) needs no checkpoint."""
        if self.config[subcommand].get("ckpt_path"):
            return
        trainable = sum(p.numel() for p in self.model.parameters() if p.requires_grad)
        if trainable:
            raise ValueError(
                f"{subcommand} without --ckpt_path would use the untrained weights of "
                f"{type(self.model).__name__} ({trainable:,} trainable parameters): give "
                "--ckpt_path PATH.ckpt, or --ckpt_path last for the newest checkpoint of the "
                "config's logger name (only a model without trainable parameters needs none)"
            )

    def parse_arguments(self, parser: Any, args: Any) -> None:
        """Parse, then resolve --ckpt_path to one file (``_checkpoint``), read it (naming it if
        unreadable) and compare the model arguments given explicitly (a re-parse without
        defaults) with its hyperparameters: evaluating it, its model class's ``TRAINING_ONLY``
        ones are ignored and its ``EVALUATION_ONLY`` ones kept in ``evaluation_arguments``;
        any other that differs is refused."""
        #: The evaluation-only model arguments given otherwise than the checkpoint's, name ->
        #: value: the model is built with them (``before_instantiate_classes``).
        self.evaluation_arguments: dict[str, Any] = {}
        #: The global step of the checkpoint --ckpt_path names (None: none named).
        self.checkpoint_step: int | None = None
        super().parse_arguments(parser, args)
        subcommand = self.config.get("subcommand")
        if subcommand not in LIGHTNING_SUBCOMMANDS:
            return
        config = self.config[subcommand]
        word = config.get("ckpt_path")
        if not word or word in runs.LIGHTNING_CHECKPOINT_WORDS:
            return
        ckpt_path = config["ckpt_path"] = str(self._checkpoint(config, word))
        checkpoint = read_checkpoint(ckpt_path)
        self.checkpoint_step = checkpoint.get("global_step")
        if word in runs.RUN_CHECKPOINT_WORDS:
            print(f"--ckpt_path {word}: {ckpt_path} (step {checkpoint.get('global_step')})")
        trained = checkpoint.get("hyper_parameters") or {}
        _refuse_retired_arguments(ckpt_path, trained)
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
        # Evaluating a checkpoint, its training-only arguments change nothing and its
        # evaluation-only ones only how it scores: no conflict.
        model_class = _import(trained["_class_path"]) if trained.get("_class_path") else None
        if not (isinstance(model_class, type) and issubclass(model_class, SurpriseModel)):
            model_class = None
        evaluating = subcommand != "fit" and model_class is not None
        training_only = model_class.TRAINING_ONLY if evaluating else ()
        evaluation_only = model_class.EVALUATION_ONLY if evaluating else ()
        given = explicit[subcommand].get("model")
        conflicts = _conflicts(given, trained, training_only + evaluation_only)
        if conflicts:
            raise ValueError(
                f"{ckpt_path} was trained with other model arguments than given here, and the "
                "model's arguments come from the checkpoint, so these would be ignored: "
                + "; ".join(conflicts)
                + ". Leave them out or give the checkpoint's values"
                + _may_differ(model_class)
                + "."
            )
        self.evaluation_arguments = {
            name: value
            for name, value in _differences(given, trained).items()
            if name in evaluation_only
        }
        if self.evaluation_arguments:
            print(
                f"{subcommand} scores {ckpt_path} with evaluation-only model arguments other "
                "than it was trained with: "
                + "; ".join(
                    f"{name}: {value} (trained with {trained[name]})"
                    for name, value in self.evaluation_arguments.items()
                )
            )

    @staticmethod
    def _checkpoint(config: Any, ckpt_path: str) -> Path:
        """The checkpoint file ``--ckpt_path`` names: ``last``/``best`` of the newest run of
        the config's logger name (``runs.run_checkpoint``), else the file itself."""
        if ckpt_path not in runs.RUN_CHECKPOINT_WORDS:
            return runs.checkpoint_file(ckpt_path)
        init_args = getattr(config["trainer"].get("logger"), "init_args", None) or {}
        if not init_args.get("save_dir") or not init_args.get("name"):
            raise ValueError(
                f"--ckpt_path {ckpt_path} names the newest run of the logger's "
                "save_dir and name, and the config's trainer.logger has none: give "
                "a .ckpt file"
            )
        return runs.run_checkpoint(ckpt_path, init_args["save_dir"], init_args["name"])

    def before_instantiate_classes(self) -> None:
        config = self.config.get(self.subcommand, {})
        # LightningCLI has replaced the model's arguments with the checkpoint's hyperparameters
        # since parse_arguments (its _parse_ckpt_path): the evaluation-only ones given win.
        for name, value in self.evaluation_arguments.items():
            config["model"]["init_args"][name] = value
        if self.subcommand in LIGHTNING_SUBCOMMANDS:
            _give_alpha(config)
            _give_surprise_window(config)
            preflight.check_run(self.subcommand, config)
        if config and "weights_only" in config and config.get("weights_only") is None:
            config["weights_only"] = True  # torch>=2.4 may default to unpickling anything
        if self.subcommand in LIGHTNING_SUBCOMMANDS and self.subcommand != "fit":
            self.save_config_kwargs = {
                **self.save_config_kwargs,
                "keep_earlier": True,
                "config_filename": f"{self.subcommand}_config.yaml",
            }
        ckpt_path = config.get("ckpt_path") if config else None
        if ckpt_path and ckpt_path not in runs.LIGHTNING_CHECKPOINT_WORDS:
            checkpoint = Path(ckpt_path)  # an existing file: parse_arguments resolved it
            if checkpoint.parent.name == "checkpoints":
                self._log_into_run(config, checkpoint)
        if self.subcommand in LIGHTNING_SUBCOMMANDS:
            preflight.check_logger(config)

    def _log_into_run(self, config: Any, checkpoint: Path) -> None:
        """Point a logger with save_dir/name/version (TensorBoard, CSV) at the checkpoint's
        run, and for ``validate``/``test``/``predict`` at the folder ``runs.report_folder``
        gives this checkpoint, data root, concepts and benchmark there."""
        init_args = getattr(config["trainer"].get("logger"), "init_args", None)
        if init_args is None or not all(
            key in init_args for key in ("save_dir", "name", "version")
        ):
            return
        run_dir = checkpoint.parent.parent
        version = run_dir.name
        if self.subcommand == "fit" and config.get("branch"):
            print(
                f"fit --branch: continues from {checkpoint} in a new version of "
                f"{run_dir.parent} (the run {run_dir} and its record are kept as they are)"
            )
            version = None  # the logger's next version
        elif self.subcommand == "fit":
            self._keep_record(config, checkpoint, run_dir)
        if (
            self.subcommand == "fit"
            and not config.get("branch")
            and init_args.get("name") not in (None, run_dir.parent.name)
        ):
            rank_zero_warn(
                f"fit --ckpt_path resumes in the checkpoint's run {run_dir}, so its curves and "
                f"checkpoints continue there; the logger name {init_args['name']!r} is not "
                "used. A later test of this run replaces its voe_report/: copy it first to keep it."
            )
        folder = (
            _report_folder(config, checkpoint, self.evaluation_arguments)
            if self.subcommand != "fit"
            else None
        )
        if folder is not None:
            version = f"{version}/{folder}"
            print(
                f"{self.subcommand} of {checkpoint} on other data, concepts or another "
                f"checkpoint than the run's own, or scored otherwise: its logs and report go "
                f"to {run_dir / folder}, and the run's own voe_report/ is kept"
            )
        init_args["save_dir"] = str(run_dir.parent.parent)
        init_args["name"] = run_dir.parent.name
        init_args["version"] = version

    def _keep_record(self, config: Any, checkpoint: Path, run_dir: Path) -> None:
        """A resumed ``fit`` trains on the data of the run's record (its saved config.yaml; a
        difference is refused naming both values; the model's arguments are compared with the
        checkpoint's in ``parse_arguments``) and saves its own config beside it, never over it
        (``config_resumed_step<N>.yaml``)."""
        given = yaml.safe_load(self._parser("fit").dump(config, skip_none=False))
        differences = runs.record_differences(run_dir / runs.RUN_CONFIG, given)
        if differences:
            raise ValueError(
                f"fit --ckpt_path {checkpoint} resumes the run {run_dir}, which trained on other "
                f"data than given: {'; '.join(differences)}. Resume with the run's values, "
                "or add --branch true to continue from it in a new version"
            )
        step = "" if self.checkpoint_step is None else f"_step{self.checkpoint_step}"
        name = runs.fresh_config_name(run_dir, f"config_resumed{step}")
        self.save_config_kwargs = {**self.save_config_kwargs, "config_filename": name}


def _refuse_retired_arguments(ckpt_path: str, trained: dict) -> None:
    """Refuse a checkpoint whose model arguments include some its model class no longer takes
    (a checkpoint of an older version), naming them, before the model is built."""
    if not trained.get("_class_path"):
        return
    model_class = _import(trained["_class_path"])
    parameters = inspect.signature(model_class.__init__).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values()):
        return
    retired = sorted(
        name for name in trained if not name.startswith("_") and name not in parameters
    )
    if retired:
        raise ValueError(
            f"{ckpt_path} holds model arguments {model_class.__name__} no longer takes: "
            f"{', '.join(retired)} (a checkpoint of an older version?); test it with the version "
            "that wrote it"
        )


def _callbacks_taking(config: Any, argument: str) -> list[tuple[str, Any]]:
    """(class path, init_args) of each configured callback whose class takes ``argument``."""
    taking = []
    for callback in config["trainer"].get("callbacks") or []:
        class_path = getattr(callback, "class_path", None)
        if class_path is None:
            continue
        if argument not in inspect.signature(_import(class_path).__init__).parameters:
            continue
        if callback.get("init_args") is None:
            callback["init_args"] = Namespace()
        taking.append((class_path, callback["init_args"]))
    return taking


def _give_surprise_window(config: Any) -> None:
    """Hand the run's ``surprise_window`` (checked) to every configured callback that takes
    one and was not given one."""
    window = surprise_window(config.get("surprise_window")).as_config()
    for _, init_args in _callbacks_taking(config, "surprise_window"):
        if init_args.get("surprise_window") is None:
            init_args["surprise_window"] = window


def _give_alpha(config: Any) -> None:
    """Hand the run's ``alpha`` to every configured callback that takes one and was not given
    one; refuse a callback whose own alpha differs (one alpha per run, docs/architecture.md
    §8)."""
    alpha = statistics.check_alpha(config["alpha"])
    for class_path, init_args in _callbacks_taking(config, "alpha"):
        given = init_args.get("alpha")
        if given is None:
            init_args["alpha"] = alpha
        elif given != alpha:
            raise ValueError(
                f"{class_path} was given alpha {given}, the run's alpha is {alpha}: a run has one "
                "significance level. Set it once, as the top-level `alpha:` of a config (e.g. "
                "configs/base.yaml) or --alpha, and leave the callbacks' alpha out."
            )


def _report_folder(config: Any, checkpoint: Path, evaluation: dict[str, Any]) -> str | None:
    """``runs.report_folder`` of evaluating ``checkpoint`` with ``config``'s data and the
    ``evaluation``-only model arguments given otherwise, compared with the data and concepts
    of the run's training config (``<run>/config.yaml``)."""
    data = config.get("data")
    data_args = getattr(data, "init_args", None) or {}
    data_class = _import(data.class_path) if getattr(data, "class_path", None) else None
    # An external benchmark's DataModule describes its pairs for its own metrics; ours do not.
    benchmark = None
    if data_class is not None and data_class.external_pairs is not ProbeDataModule.external_pairs:
        logger_args = getattr(config["trainer"].get("logger"), "init_args", None) or {}
        benchmark = logger_args.get("name") or data_class.__name__
    try:
        trained = yaml.safe_load((checkpoint.parent.parent / "config.yaml").read_text())
        trained_args = trained["data"]["init_args"]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        trained_args = {}
    return runs.report_folder(
        checkpoint,
        runs.probe_root(data_args),
        runs.concepts_of(data_args),
        benchmark,
        runs.probe_root(trained_args),
        runs.concepts_of(trained_args),
        evaluation,
    )


def _differences(given: Any, trained: dict) -> dict[str, Any]:
    """Each model argument in ``given`` (the explicitly given model section) that the
    checkpoint's hyperparameters ``trained`` hold otherwise: name -> the given value."""
    if not isinstance(given, Namespace) or not trained:
        return {}
    arguments = given.get("init_args")
    arguments = arguments.as_dict() if isinstance(arguments, Namespace) else {}
    return {
        name: value
        for name, value in arguments.items()
        if name in trained and _plain(value) != _plain(trained[name])
    }


def _conflicts(given: Any, trained: dict, ignored: tuple[str, ...] = ()) -> list[str]:
    """'name: config X, checkpoint Y' for each of ``_differences`` except those ``ignored``,
    after a model class that differs from the checkpoint's."""
    if not isinstance(given, Namespace) or not trained:
        return []
    conflicts = [
        f"{name}: config {value!r}, checkpoint {trained[name]!r}"
        for name, value in _differences(given, trained).items()
        if name not in ignored
    ]
    class_path, trained_class_path = given.get("class_path"), trained.get("_class_path")
    if class_path and trained_class_path and _import(class_path) is not _import(trained_class_path):
        conflicts.insert(0, f"class_path: config {class_path!r}, checkpoint {trained_class_path!r}")
    return conflicts


def _may_differ(model_class: type[SurpriseModel] | None) -> str:
    """For a refusal: which model arguments evaluating a checkpoint of ``model_class`` may
    give otherwise, its training-only and evaluation-only ones ("" for none)."""
    if model_class is None:
        return ""
    kinds = [
        f"{kind} {', '.join(names)} ({effect})"
        for kind, names, effect in (
            ("training-only", model_class.TRAINING_ONLY, "ignored"),
            ("evaluation-only", model_class.EVALUATION_ONLY, "used instead of the checkpoint's"),
        )
        if names
    ]
    if not kinds:
        return ""
    return (
        f"; validate, test and predict of it take other values of {model_class.__name__}'s "
        + " and ".join(kinds)
    )


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
    parser.add_argument(
        "--config",
        action=ActionConfigFile,
        help="a YAML file of these arguments (see --print_config)",
    )
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
    """Call the function of a ``COMMANDS`` entry that its parsed ``arguments`` select; one that
    runs other commands (``analyze sweep``) gets this CLI's ``main`` as ``_cli_main``, one that
    builds runs without running them (``analyze null``) ``_build_cli`` (``_cli``, not run)."""
    arguments = arguments.clone()
    arguments.pop("config", None)
    if isinstance(command, dict):
        name = arguments.pop("subcommand")
        return _call(command[name], arguments[name])
    entry_points = {"_cli_main": main, "_build_cli": functools.partial(_cli, run=False)}
    parameters = inspect.signature(command).parameters
    return command(
        **{name: _built(value) for name, value in vars(arguments).items()},
        **{key: value for key, value in entry_points.items() if key in parameters},
    )


def _built(value: Any) -> Any:
    """A parsed ``class_path``/``init_args`` value (``check-causality --model``) as the object
    it describes; any other value as it is."""
    if not (isinstance(value, Namespace) and "class_path" in value):
        return value
    init_args = value.get("init_args")
    return _import(value["class_path"])(**(init_args.as_dict() if init_args else {}))


def main(args: list[str] | None = None) -> Any:
    """Entry point of ``python -m voe_lightning``; tests call ``main([...])``. Returns the CLI,
    or for a subcommand of ``COMMANDS`` its function's return value. A bad argument or input
    (``USER_ERRORS``, raised here or in a DataLoader worker) is printed as one line,
    ``error: ...``, and exits with status 2; with
    ``--debug`` anywhere among the arguments, or ``VOE_DEBUG=1``, it raises instead."""
    words = list(sys.argv[1:] if args is None else args)
    debug = "--debug" in words or os.environ.get(DEBUG_VARIABLE, "") not in ("", "0")
    words = [word for word in words if word != "--debug"]
    if args is None:
        sys.argv[1:] = words  # LightningCLI reads the command line itself
    try:
        _check_yaml(words)
        _check_classes(words)
        cli = _cli(None if args is None else words)
    except Exception as error:
        message = _user_message(error)
        if debug or message is None:
            raise
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(2) from error
    return cli.result if cli.subcommand in COMMANDS else cli


#: The most values a ``--config`` file may expand to through its YAML aliases (a paper config
#: holds a few hundred; nested anchors can make 700 bytes hold 10^9, which would hang).
MAX_CONFIG_VALUES = 100_000


def _check_yaml(words: list[str]) -> None:
    """Refuse a ``--config`` file that is not valid YAML, naming it (jsonargparse's message
    gives the line and column of "<unicode string>"), or that expands to more than
    ``MAX_CONFIG_VALUES`` values through its aliases."""
    files = [word.split("=", 1)[1] for word in words if word.startswith("--config=")]
    files += [after for word, after in zip(words, words[1:]) if word == "--config"]
    for name in files:
        if Path(name).is_dir():
            found = sorted(Path(name).glob("*.yaml"))
            raise ValueError(
                f"--config {name} is a directory, not a YAML file; give one file"
                + (f", e.g. {found[0]}" if found else "")
            )
        try:
            document = yaml.compose(Path(name).read_text(), Loader=yaml.SafeLoader)
        except OSError:
            continue  # the parser names a missing file itself
        except yaml.YAMLError as error:
            mark = getattr(error, "problem_mark", None)
            where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            problem = getattr(error, "problem", None) or error
            raise ValueError(f"--config {name} is not valid YAML{where}: {problem}") from None
        if document is not None and _expanded_size(document, {}) > MAX_CONFIG_VALUES:
            raise ValueError(
                f"--config {name} expands to more than {MAX_CONFIG_VALUES:,} values "
                "through its YAML aliases (*name repeating &name): refused; a "
                "config needs no more"
            )


#: Flags whose value may be a class's import path, with an example of one.
CLASS_FLAGS = {"--model": "voe_lightning.model.VRNNLRUModel", "--data": "my_package.MyDataModule"}


def _check_classes(words: list[str]) -> None:
    """Refuse a ``--model``/``--data`` import path (``package.module.Class``; not a file)
    that cannot be imported, naming it and why (the parser prints its usage over the cause)."""
    given = [(flag, value) for flag, value in zip(words, words[1:]) if flag in CLASS_FLAGS]
    given += [
        tuple(word.split("=", 1))
        for word in words
        if "=" in word and word.split("=", 1)[0] in CLASS_FLAGS
    ]
    for flag, value in given:
        if (
            not re.fullmatch(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+", value)
            or Path(value).exists()
            or Path(value).suffix in (".yaml", ".yml", ".json")
        ):
            continue
        try:
            _import(value)
        except (ImportError, AttributeError) as error:
            raise ValueError(
                f"{flag} {value} cannot be imported ({error}); give a class's "
                f"import path, e.g. {CLASS_FLAGS[flag]}"
            ) from None


def _expanded_size(node: yaml.Node, sizes: dict[int, int]) -> int:
    """How many values the YAML ``node`` holds with every alias expanded, counted once per
    distinct node (``sizes``: by id), so a billion-value alias bomb costs microseconds."""
    if id(node) not in sizes:
        sizes[id(node)] = 1  # a node that contains itself counts once
        children = (
            [part for pair in node.value for part in pair]
            if isinstance(node, yaml.MappingNode)
            else node.value
            if isinstance(node, yaml.SequenceNode)
            else []
        )
        sizes[id(node)] = 1 + sum(_expanded_size(child, sizes) for child in children)
    return sizes[id(node)]


#: How torch's DataLoader re-raises in this process an error a worker process raised: the
#: worker's whole traceback as its message, whose last line is "module.Type: message".
WORKER_ERROR = re.compile(
    r"Caught \w+ in DataLoader worker process \d+\.\n"
    r"Original Traceback \(most recent call last\):\n.*\n"
    r"(?P<type>[\w.]+): (?P<message>.*?)\n?\Z",
    re.S,
)


def _user_message(error: BaseException) -> str | None:
    """The message of the error the user's value caused (None: not one of ``USER_ERRORS``, a
    bug whose traceback shows): jsonargparse wraps a class's ValueError in one of its own
    that lists every type it tried, so unwrap those; a DataLoader worker's error is the
    worker's own one line, as in the main process (torch re-raises it with the worker's
    traceback as its message, or as a RuntimeError where its type takes other arguments)."""
    while error.__cause__ is not None and _raised_in(error, "jsonargparse"):
        error = error.__cause__
    worker = WORKER_ERROR.match(str(error.args[0]) if error.args else "")
    if worker is None:
        return str(error) if isinstance(error, USER_ERRORS) else None
    module, _, name = worker["type"].rpartition(".")
    try:
        original = getattr(importlib.import_module(module) if module else builtins, name, None)
    except ImportError:
        original = None
    if isinstance(original, type) and issubclass(original, USER_ERRORS):
        return worker["message"]
    return None


def _raised_in(error: BaseException, package: str) -> bool:
    """Whether ``error`` was raised by code of ``package``."""
    frames = traceback.extract_tb(error.__traceback__)
    return bool(frames) and f"{os.sep}{package}{os.sep}" in frames[-1].filename


def _cli(args: list[str] | None, run: bool = True) -> VOECLI:
    """The VOECLI of ``args`` (None: the command line), run; with ``run`` False, its model,
    data and trainer built from ``args`` (configs after base.yaml, no subcommand) and not run
    (``analyze null`` tests untrained initializations so, through ``_call``)."""
    return VOECLI(
        model_class=SurpriseModel,
        datamodule_class=ProbeDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        seed_everything_default=0,
        save_config_callback=runs.RunConfig,
        save_config_kwargs={"overwrite": True},
        parser_kwargs={
            "prog": "python -m voe_lightning",
            "description": "Probe video models' intuitive physics by violation of "
            "expectation: generate the data, train and test, audit cues, analyze runs. "
            "A bad argument or input is one line, 'error: ...'; --debug anywhere "
            f"(or {DEBUG_VARIABLE}=1) shows its traceback.",
            **(
                {
                    name: {"default_config_files": [str(BASE_CONFIG)]}
                    for name in LIGHTNING_SUBCOMMANDS
                }
                if run
                else {"default_config_files": [str(BASE_CONFIG)]}
            ),
        },
        args=args,
        run=run,
    )
