"""The model arguments a run gives matched against its checkpoint's hyperparameters: LightningCLI
builds the model from the checkpoint's, so a model argument given otherwise would be silently
ignored and is refused, except, evaluating the checkpoint, its model class's ``TRAINING_ONLY``
ones (they change nothing) and ``EVALUATION_ONLY`` ones (used instead of the checkpoint's); so is
a checkpoint holding arguments its class no longer takes. The model section given is a plain
mapping (``class_path``, ``init_args``), the hyperparameters as the checkpoint holds them."""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

from voe_lightning.class_paths import import_failure, import_object
from voe_lightning.model import SurpriseModel


def refuse_retired_arguments(ckpt_path: str, trained: Mapping[str, Any]) -> None:
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


def evaluation_arguments(
    subcommand: str, ckpt_path: str, given: Mapping[str, Any] | None, trained: Mapping[str, Any]
) -> dict[str, Any]:
    """The evaluation-only model arguments ``given`` (the explicit model section) otherwise
    than the checkpoint's hyperparameters ``trained``, name -> given value, said in a line;
    any other that differs is refused, naming it with both values."""
    model_class = _model_class(trained)
    # Evaluating a checkpoint, its training-only arguments change nothing and its
    # evaluation-only ones only how it scores: no conflict.
    evaluated = model_class if subcommand != "fit" else None
    training_only = evaluated.TRAINING_ONLY if evaluated else ()
    evaluation_only = evaluated.EVALUATION_ONLY if evaluated else ()
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
    evaluation = {
        name: value
        for name, value in _differences(given, trained).items()
        if name in evaluation_only
    }
    if evaluation:
        print(
            f"{subcommand} scores {ckpt_path} with evaluation-only model arguments other "
            "than it was trained with: "
            + "; ".join(
                f"{name}: {value} (trained with {trained[name]})"
                for name, value in evaluation.items()
            )
        )
    return evaluation


def _model_class(trained: Mapping[str, Any]) -> type[SurpriseModel] | None:
    """The ``SurpriseModel`` class the checkpoint's hyperparameters name (None: none)."""
    model_class = import_object(trained["_class_path"]) if trained.get("_class_path") else None
    if isinstance(model_class, type) and issubclass(model_class, SurpriseModel):
        return model_class
    return None


def _differences(given: Mapping[str, Any] | None, trained: Mapping[str, Any]) -> dict[str, Any]:
    """Each model argument in ``given`` (the explicitly given model section) that the
    checkpoint's hyperparameters ``trained`` hold otherwise: name -> the given value."""
    if given is None or not trained:
        return {}
    arguments = given.get("init_args")
    arguments = arguments if isinstance(arguments, Mapping) else {}
    return {
        name: value
        for name, value in arguments.items()
        if name in trained and _plain(value) != _plain(trained[name])
    }


def _conflicts(
    given: Mapping[str, Any] | None, trained: Mapping[str, Any], ignored: tuple[str, ...] = ()
) -> list[str]:
    """'name: config X, checkpoint Y' for each of ``_differences`` except those ``ignored``,
    after a model class that differs from the checkpoint's."""
    if given is None or not trained:
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
