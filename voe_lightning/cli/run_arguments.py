"""The run-wide arguments beside the trainer's, model's and data's (``configs/base.yaml`` sets
them): one ``alpha`` and ``surprise_window`` for each callback; ``branch``, ``allow_non_causal``."""

from __future__ import annotations

import inspect
from typing import Any, Optional

import yaml
from jsonargparse import Namespace
from jsonargparse.typing import register_type

from voe_lightning.class_paths import import_object
from voe_lightning.runs import base_alpha
from voe_lightning.stats import statistics
from voe_lightning.stats.surprise_window import ALL, SurpriseWindow, surprise_window


def _window_from_config(value: Any) -> SurpriseWindow:
    """A ``SurpriseWindow`` from a config's or a command line's value (YAML text there)."""
    return surprise_window(yaml.safe_load(value) if isinstance(value, str) else value)


# A surprise window is parsed once, where the parser reads it; saved configs keep its config form.
register_type(SurpriseWindow, serializer=SurpriseWindow.as_config, deserializer=_window_from_config)


def add_run_arguments(parser: Any) -> None:
    """Add the run's one significance level, ``alpha`` (configs/base.yaml sets it), its
    ``surprise_window``, ``branch`` (a resumed fit in a new version) and ``allow_non_causal``."""
    parser.add_argument(
        "--alpha",
        type=float,
        default=base_alpha(),
        help="significance level of every test, verdict and table of the "
        "run; each callback with an alpha argument gets it",
    )
    parser.add_argument(
        "--surprise_window",
        type=Optional[SurpriseWindow],  # noqa: UP045 (jsonargparse's type)
        default=ALL,
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


def give_run_arguments(config: Any) -> None:
    """Hand the run's ``alpha`` and ``surprise_window`` to each configured callback that takes one
    and was given none; refuse a callback's other alpha (one per run, docs/architecture.md §8)."""
    alpha = statistics.check_alpha(config["alpha"])
    window = config["surprise_window"] or SurpriseWindow()
    for argument, value in (("alpha", alpha), ("surprise_window", window)):
        for class_path, init_args in _callbacks_taking(config, argument):
            given = init_args.get(argument)
            if given is None:
                init_args[argument] = value
            elif argument == "alpha" and given != alpha:
                raise ValueError(
                    f"{class_path} was given alpha {given}, the run's alpha is {alpha}: a run "
                    "has one significance level. Set it once, as the top-level `alpha:` of a "
                    "config (e.g. configs/base.yaml) or --alpha, and leave the callbacks' "
                    "alpha out."
                )


def _callbacks_taking(config: Any, argument: str) -> list[tuple[str, Any]]:
    """(class path, init_args) of each configured callback whose class takes ``argument``."""
    taking = []
    for callback in config["trainer"].get("callbacks") or []:
        class_path = getattr(callback, "class_path", None)
        if class_path is None:
            continue
        if argument not in inspect.signature(import_object(class_path).__init__).parameters:
            continue
        if callback.get("init_args") is None:
            callback["init_args"] = Namespace()  # type: ignore[no-untyped-call]  # jsonargparse: unannotated
        taking.append((class_path, callback["init_args"]))
    return taking
