"""The model arguments given with ``--ckpt_path`` matched against the checkpoint's
hyperparameters: LightningCLI builds the model from the checkpoint's, so a model argument given
otherwise would be silently ignored and is refused, except, evaluating the checkpoint, its
model class's ``TRAINING_ONLY`` ones (they change nothing) and ``EVALUATION_ONLY`` ones (used
instead of the checkpoint's); so is a checkpoint holding arguments its class no longer takes."""

from __future__ import annotations

import inspect
import sys
from typing import Any

from jsonargparse import Namespace

from voe_lightning.cli.class_paths import import_failure, import_object
from voe_lightning.model import SurpriseModel
from voe_lightning.runs import BASE_CONFIG


def refuse_retired_arguments(ckpt_path: str, trained: dict) -> None:
    """Refuse a checkpoint whose model class does not import, or whose model arguments include
    some its model class no longer takes (a checkpoint of an older version), naming them, before
    the model is built; ``migrate`` rewrites a run saved under old paths."""
    if not trained.get("_class_path"):
        return
    migrate = (
        f"`python -m voe_lightning migrate {ckpt_path}` (it unpickles the checkpoint, which "
        "can run code: only one you trust)"
    )
    class_path = trained["_class_path"]
    try:
        model_class = import_object(class_path)
    except Exception as error:  # any error importing it: the module's own too
        raise ValueError(
            f"{ckpt_path} names its model class {class_path}, which does not import "
            f"({import_failure(error)}); a run saved under an old path is rewritten by "
            f"{migrate}"
        ) from error
    if not (isinstance(model_class, type) and issubclass(model_class, SurpriseModel)):
        raise ValueError(
            f"{ckpt_path} names its model class {class_path}, which is a "
            f"{type(model_class).__name__}, not a subclass of SurpriseModel; a checkpoint of "
            f"this package names one, e.g. voe_lightning.model.VRNNLRUModel"
        )
    parameters = inspect.signature(model_class.__init__).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values()):
        return
    retired = sorted(
        name for name in trained if not name.startswith("_") and name not in parameters
    )
    if retired:
        raise ValueError(
            f"{ckpt_path} holds model arguments {model_class.__name__} no longer takes: "
            f"{', '.join(retired)} (a checkpoint of an older version?); rewrite it with "
            f"{migrate}, or test it with the version that wrote it"
        )


def explicit_model(parser: Any, args: Any, subcommand: str, trained: dict) -> Any:
    """The model section of ``subcommand`` as given explicitly (a re-parse without defaults),
    the checkpoint's model class ``trained["_class_path"]`` standing for base.yaml's."""
    if isinstance(args, (dict, Namespace)):
        return parser.parse_object(args, defaults=False)[subcommand].get("model")
    # Without defaults, base.yaml (a default config file) is missing too, and a study
    # config's partial sections would not parse: read it first, explicitly, with the
    # checkpoint's model class (base.yaml gives a class_path only), as the run will.
    words = list(sys.argv[1:] if args is None else args)
    at = words.index(subcommand) + 1
    if trained.get("_class_path"):
        words[at:at] = ["--model", trained["_class_path"]]
    if BASE_CONFIG.is_file():
        words[at:at] = ["--config", str(BASE_CONFIG)]
    return parser.parse_args(words, defaults=False)[subcommand].get("model")


def evaluation_arguments(
    subcommand: str, ckpt_path: str, given: Any, trained: dict
) -> dict[str, Any]:
    """The evaluation-only model arguments ``given`` (the explicit model section) otherwise
    than the checkpoint's hyperparameters ``trained``, name -> given value; any other that
    differs is refused, naming it with both values."""
    model_class = _model_class(trained)
    # Evaluating a checkpoint, its training-only arguments change nothing and its
    # evaluation-only ones only how it scores: no conflict.
    evaluating = subcommand != "fit" and model_class is not None
    training_only = model_class.TRAINING_ONLY if evaluating else ()
    evaluation_only = model_class.EVALUATION_ONLY if evaluating else ()
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
    return {
        name: value
        for name, value in _differences(given, trained).items()
        if name in evaluation_only
    }


def evaluation_note(
    subcommand: str, ckpt_path: str, evaluation: dict[str, Any], trained: dict
) -> str:
    """The line saying which ``evaluation``-only arguments score the checkpoint otherwise."""
    return (
        f"{subcommand} scores {ckpt_path} with evaluation-only model arguments other "
        "than it was trained with: "
        + "; ".join(
            f"{name}: {value} (trained with {trained[name]})" for name, value in evaluation.items()
        )
    )


def _model_class(trained: dict) -> type[SurpriseModel] | None:
    """The ``SurpriseModel`` class the checkpoint's hyperparameters name (None: none)."""
    model_class = import_object(trained["_class_path"]) if trained.get("_class_path") else None
    if isinstance(model_class, type) and issubclass(model_class, SurpriseModel):
        return model_class
    return None


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
        # recorded from the training batches: a config (a run's saved one) that gives none
        and not (name == "training_frames" and value is None)
    ]
    class_path, trained_class_path = given.get("class_path"), trained.get("_class_path")
    if (
        class_path
        and trained_class_path
        and import_object(class_path) is not import_object(trained_class_path)
    ):
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
