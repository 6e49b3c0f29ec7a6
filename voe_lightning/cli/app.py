"""The command line: Lightning's ``fit``/``validate``/``test``/``predict`` and the package's own
subcommands (``commands``) in one parser: one flag style, ``--config`` for all, one ``--help``."""

from __future__ import annotations

import functools
import inspect
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import yaml
from jsonargparse import Namespace
from lightning.pytorch import Callback
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.utilities.exceptions import SIGTERMException

from voe_lightning import checkpoint_arguments, run_folders, runs
from voe_lightning.analysis import null
from voe_lightning.callbacks import VOEReportCallback
from voe_lightning.callbacks.interruption import InterruptCheckpoint, ctrl_c_kept
from voe_lightning.callbacks.outcomes import probe_outcomes
from voe_lightning.cli import commands, parser_errors, preflight, run_arguments, user_errors
from voe_lightning.cli.commands import COMMANDS, LIGHTNING_SUBCOMMANDS
from voe_lightning.cli.user_errors import DEBUG_VARIABLE
from voe_lightning.model import SurpriseModel
from voe_lightning.model.scorers.callable_model import CallableError
from voe_lightning.probe_datamodule import ProbeDataModule
from voe_lightning.runs import BASE_CONFIG, SHIPPED_CONFIGS, read_checkpoint

#: Exit status of a fit/validate/test whose probe surprise is not causal (report without verdicts).
NOT_CAUSAL_EXIT = 3
#: Exit status of a command stopped by Ctrl-C (128 + SIGINT, as a shell's).
INTERRUPTED_EXIT = 130
#: What an evaluation stopped by Ctrl-C leaves (a report is written whole or not at all).
EVALUATION_INTERRUPTED = "nothing written (no report, no predictions; one written before is kept)"


class VOECLI(LightningCLI):
    """LightningCLI with the package's subcommands beside Lightning's, whose runs are checked before
    any work and log into their checkpoint's run folder. Exits: 128 + a SIGTERM/SIGINT's number for
    a stopped run, ``NOT_CAUSAL_EXIT``, ``INTERRUPTED_EXIT`` where Ctrl-C stopped anything else."""

    def setup_parser(
        self, add_subcommands: bool, main_kwargs: dict[str, Any], subparser_kwargs: dict[str, Any]
    ) -> None:
        """Lightning's parser and subcommands, then those of ``COMMANDS`` beside them."""
        super().setup_parser(add_subcommands, main_kwargs, subparser_kwargs)
        if add_subcommands:
            assert isinstance(self.parser, commands.SubcommandsParser)  # _cli's parser_class
            commands.add_commands(self.parser.subcommands, COMMANDS)

    def add_arguments_to_parser(self, parser: Any) -> None:
        """The run-wide arguments: ``run_arguments.add_run_arguments``."""
        run_arguments.add_run_arguments(parser)

    def parse_arguments(self, parser: Any, args: Any) -> None:
        """Parse; then a ``COMMANDS`` subcommand is not seeded, and a Lightning one's
        ``--ckpt_path`` is checked against its model arguments (``_match_checkpoint``)."""
        #: The evaluation-only model arguments given otherwise than the checkpoint's: name -> value.
        self.evaluation_arguments: dict[str, Any] = {}
        #: The global step of the checkpoint --ckpt_path names (None: none named).
        self.checkpoint_step: int | None = None
        super().parse_arguments(parser, args)
        subcommand = self.config.get("subcommand")
        if subcommand in COMMANDS:
            self.config[subcommand]["seed_everything"] = False  # those have no seed to set
        elif subcommand in LIGHTNING_SUBCOMMANDS:
            self._match_checkpoint(parser, args, subcommand)

    def _match_checkpoint(self, parser: Any, args: Any, subcommand: str) -> None:
        """Resolve --ckpt_path to one file and read it; match the model arguments given with its
        hyperparameters (``checkpoint_arguments``), keeping the evaluation-only ones."""
        config = self.config[subcommand]
        word = config.get("ckpt_path")
        if not word or word in runs.LIGHTNING_CHECKPOINT_WORDS:
            return
        ckpt_path = config["ckpt_path"] = str(run_folders.checkpoint_file(config, word))
        checkpoint = read_checkpoint(ckpt_path)
        self.checkpoint_step = checkpoint.get("global_step")
        if word in runs.RUN_CHECKPOINT_WORDS:
            print(f"--ckpt_path {word}: {ckpt_path} (step {self.checkpoint_step})")
        trained = checkpoint.get("hyper_parameters") or {}
        checkpoint_arguments.refuse_retired_arguments(ckpt_path, trained)
        given = _explicit_model(parser, args, subcommand, trained)
        self.evaluation_arguments = checkpoint_arguments.evaluation_arguments(
            subcommand, ckpt_path, given, trained
        )

    def before_instantiate_classes(self) -> None:
        """Complete and check a run's config before anything is built: evaluation-only model
        arguments, run-wide arguments, preflight, saved config's name, logger's run folder."""
        if self.subcommand in COMMANDS:
            return  # a function called with its arguments: no model, data or trainer
        # A CLI built without running (run=False: ``analyze null``) has no subcommand level.
        config = self.config if self.subcommand is None else self.config[self.subcommand]
        # LightningCLI's _parse_ckpt_path gave the model the checkpoint's arguments: these win.
        for name, value in self.evaluation_arguments.items():
            config["model"]["init_args"][name] = value
        run_arguments.give_run_arguments(config)
        if self.subcommand is not None:
            preflight.check_run(self.subcommand, config)
        if "weights_only" in config and config.get("weights_only") is None:
            config["weights_only"] = True  # torch>=2.4 may default to unpickling anything
        if self.subcommand not in (None, "fit"):
            self.save_config_kwargs = {
                **self.save_config_kwargs,
                "keep_earlier": True,
                "config_filename": f"{self.subcommand}_config.yaml",
            }
        run_folders.log_into_run(
            self.subcommand, config, self.evaluation_arguments, self._keep_record
        )
        if self.subcommand is not None:
            run_folders.check_run_folder(config)

    def _keep_record(self, checkpoint: Path, run_dir: Path) -> None:
        """A resumed ``fit`` saves its config beside the run's record, never over it
        (``run_folders.resumed_config_name``, which refuses other data than the record's)."""
        name = run_folders.resumed_config_name(
            checkpoint, run_dir, self._saved_config(), self.checkpoint_step
        )
        self.save_config_kwargs = {**self.save_config_kwargs, "config_filename": name}

    def _saved_config(self) -> dict[str, Any]:
        """This subcommand's config as its saved config file holds it, None values kept."""
        saved = yaml.safe_load(self.parser.dump(self.config, skip_none=False))
        return cast(dict[str, Any], saved[self.subcommand])

    def _callbacks(self) -> list[Callback]:
        """The trainer's callbacks (set by its CallbackConnector, undeclared on ``Trainer``)."""
        return cast(list[Callback], self.trainer.callbacks)  # type: ignore[attr-defined]

    def instantiate_classes(self) -> None:
        """Lightning's model, data and trainer; none for a subcommand of ``COMMANDS``."""
        if self.subcommand not in COMMANDS:
            super().instantiate_classes()

    # Private: Lightning runs a subcommand only as the Trainer's method; no public hook runs another.
    def _run_subcommand(self, subcommand: str) -> None:
        """Call a ``COMMANDS`` function (its return value in ``self.result``), or run the
        Trainer's method: a run stopped by SIGTERM/SIGINT exits with 128 + its number."""
        if subcommand in COMMANDS:
            arguments = self.config[subcommand].clone()
            del arguments["seed_everything"]  # parse_arguments' False: not the function's
            entry_points: dict[str, Callable[..., Any]] = {
                "_cli_main": main,
                "_build_cli": functools.partial(_cli, run=False),
            }
            try:
                with ctrl_c_kept():  # analyze null tests through Lightning too
                    self.result = commands.call(COMMANDS[subcommand], arguments, entry_points)
            except KeyboardInterrupt as stopped:
                kept = commands.INTERRUPTED[subcommand]
                raise SystemExit(interrupted(subcommand, kept)) from stopped
            return
        callbacks = self._callbacks()
        interrupt = next((c for c in callbacks if isinstance(c, InterruptCheckpoint)), None)
        if interrupt is None:  # every fit saves a resumable checkpoint; SIGTERM stops the rest
            interrupt = InterruptCheckpoint()
            callbacks.append(interrupt)
        try:
            with ctrl_c_kept():
                super()._run_subcommand(subcommand)
        except SIGTERMException as stopped:
            print(interrupt.stopped(subcommand, self.trainer.global_step), file=sys.stderr)
            raise SystemExit(interrupt.exit_code()) from stopped
        except KeyboardInterrupt as stopped:
            kept = (
                f"nothing saved at step {self.trainer.global_step} (checkpoints saved before "
                "are kept; a first Ctrl-C while it trains saves a resumable one)"
                if subcommand == "fit"
                else EVALUATION_INTERRUPTED
            )
            raise SystemExit(interrupted(subcommand, kept)) from stopped

    def before_test(self) -> None:
        """No test of untrained weights; where a report callback asks for ``priors_alone``, first
        the run's config as tested at initialization (``null.priors_alone_first``)."""
        self._refuse_untrained("test")
        asking = [
            callback
            for callback in self._callbacks()
            if isinstance(callback, VOEReportCallback) and callback.priors_alone
        ]
        if not asking:
            return
        saved = self._saved_config()
        own = set(inspect.signature(self.trainer.test).parameters) - self.subcommands()["test"]
        for key in ("config", *own):  # ckpt_path, verbose...: the untrained copy has none
            saved.pop(key, None)
        seed = self.config["test"].get("seed_everything")
        out = Path(self.trainer.log_dir or ".") / runs.UNTRAINED_FOLDER
        null.priors_alone_first(asking, functools.partial(_cli, run=False), saved, seed, out)

    def after_fit(self) -> None:
        """Exit ``NOT_CAUSAL_EXIT`` where the surprise was not causal; else say what to run next."""
        self._exit_if_not_causal("fit")
        run = Path(self.trainer.log_dir or ".")
        callback = self.trainer.checkpoint_callback
        checkpoint = isinstance(callback, ModelCheckpoint) and (
            callback.last_model_path or callback.best_model_path
        )
        if self.trainer.is_global_zero and checkpoint and (run / runs.RUN_CONFIG).exists():
            print(
                f"next, the report on the test probes (into {run / 'voe_report'}):\n"
                f"  python -m voe_lightning test --config {run / runs.RUN_CONFIG} "
                f"--ckpt_path {checkpoint}"
            )

    def after_validate(self) -> None:
        """Exit with ``NOT_CAUSAL_EXIT`` where the validation's surprise was not causal."""
        self._exit_if_not_causal("validate")

    def after_test(self) -> None:
        """Exit with ``NOT_CAUSAL_EXIT`` where the test's surprise was not causal."""
        self._exit_if_not_causal("test")

    def _exit_if_not_causal(self, subcommand: str) -> None:
        """Say so in one line and exit with ``NOT_CAUSAL_EXIT`` where a callback's causality
        check failed (the report and tables give no verdict), unless ``--allow_non_causal``."""
        for outcome in probe_outcomes(self._callbacks()):
            causality, where = outcome.causality, outcome.report_dir
            if causality is None or causality.causal:
                continue
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
        """No prediction from untrained weights."""
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
                "config's logger name (only a model without trainable parameters needs none: "
                "weights your own code loads, e.g. an nn.Module a CallableModel wraps, are "
                "frozen with .requires_grad_(False) where they are built)"
            )


def main(args: list[str] | None = None) -> Any:
    """Entry point of ``python -m voe_lightning``: the CLI, or a ``COMMANDS`` function's result.
    A bad argument or input is one line, ``error: ...``, exit 2 (``--debug``: raised instead)."""
    words = list(sys.argv[1:] if args is None else args)
    debug = "--debug" in words or os.environ.get(DEBUG_VARIABLE, "") not in ("", "0")
    words = [word for word in words if word != "--debug"]
    try:
        words = user_errors.shipped_config_names(words, SHIPPED_CONFIGS)
        if args is None:
            sys.argv[1:] = words  # LightningCLI reads the command line itself
        user_errors.check_yaml(words)
        user_errors.check_classes(words)
        with parser_errors.full_messages(debug):
            cli = _cli(None if args is None else words)
    except KeyboardInterrupt as stopped:
        if debug:
            raise
        names = (*LIGHTNING_SUBCOMMANDS, *COMMANDS)
        command = next((word for word in words if word in names), "the command")
        raise SystemExit(interrupted(command, "nothing written (it had not begun)")) from stopped
    except Exception as error:
        message = user_errors.user_message(error)
        if debug or message is None:
            raise
        if isinstance(error, CallableError):
            message += f" ({DEBUG_VARIABLE}=1 or --debug shows its traceback)"
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(2) from error
    return cli.result if cli.subcommand in COMMANDS else cli


def _explicit_model(
    parser: Any, args: Any, subcommand: str, trained: dict[str, Any]
) -> dict[str, Any] | None:
    """The model section of ``subcommand`` as given explicitly (a re-parse without defaults),
    the checkpoint's model class standing for base.yaml's, as a dict (None: none given)."""
    if isinstance(args, (dict, Namespace)):
        parsed = parser.parse_object(args, defaults=False)
    else:
        # Without defaults base.yaml is missing too, and a study config's partial sections would
        # not parse: read it first, with the checkpoint's model class, as the run will.
        words = list(sys.argv[1:] if args is None else args)
        at = words.index(subcommand) + 1
        if trained.get("_class_path"):
            words[at:at] = ["--model", trained["_class_path"]]
        if BASE_CONFIG.is_file():
            words[at:at] = ["--config", str(BASE_CONFIG)]
        parsed = parser.parse_args(words, defaults=False)
    model = parsed[subcommand].get("model")
    return model.as_dict() if isinstance(model, Namespace) else None


def interrupted(command: str, kept: str) -> int:
    """Say in one line that Ctrl-C stopped ``command`` and what it ``kept``; the exit status."""
    print(f"error: {command} interrupted (Ctrl-C, SIGINT): {kept}", file=sys.stderr)
    return INTERRUPTED_EXIT


def _cli(args: list[str] | None, run: bool = True) -> VOECLI:
    """The VOECLI of ``args`` (None: the command line), run; with ``run`` False, built from
    ``args`` (configs after base.yaml, no subcommand) and not run (for ``analyze null``)."""
    defaults = {"default_config_files": [str(BASE_CONFIG)]}  # base.yaml before any --config
    return VOECLI(
        model_class=SurpriseModel,
        datamodule_class=ProbeDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        seed_everything_default=0,
        save_config_callback=runs.RunConfig,
        save_config_kwargs={"overwrite": True},
        parser_class=commands.SubcommandsParser,
        parser_kwargs={
            "prog": "python -m voe_lightning",
            "description": "Probe video models' intuitive physics by violation of "
            "expectation: generate the data, train and test, audit cues, analyze runs. "
            "A bad argument or input is one line, 'error: ...'; --debug anywhere "
            f"(or {DEBUG_VARIABLE}=1) shows its traceback.",
            **({name: defaults for name in LIGHTNING_SUBCOMMANDS} if run else defaults),
        },
        args=args,
        run=run,
    )
