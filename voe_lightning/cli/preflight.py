"""Arguments checked against each other from the parsed config, before any rendering or training:
valid ones that together would train on nothing, log nothing or fail after rendering."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L
from lightning.pytorch.utilities import rank_zero_warn

from voe_lightning import specs
from voe_lightning.class_paths import import_object
from voe_lightning.runs import concepts_of


def check_run(subcommand: str, config: Any) -> None:
    """Refuse a Lightning subcommand's ``config`` whose trainer, model and data arguments contradict
    each other, saying what would be valid; warn of a fit that never validates (a smoke test's)."""
    trainer = config.get("trainer") or {}
    data = getattr(config.get("data"), "init_args", None) or {}
    model = getattr(config.get("model"), "init_args", None) or {}
    max_steps = trainer.get("max_steps")
    if isinstance(max_steps, int) and max_steps < -1:
        raise ValueError(
            f"trainer.max_steps {max_steps}: give a number of steps >= 0, or -1 for no limit"
        )
    _check_image_size(model, data)
    root = data.get("root")
    if root is not None and Path(root).exists() and not Path(root).is_dir():
        raise NotADirectoryError(
            f"data.init_args.root {root} is a file, not a dataset folder: "
            "give a folder (generate makes it where it does not exist)"
        )
    data_class = getattr(config.get("data"), "class_path", None)
    if subcommand == "predict" and data_class and not _predicts(data_class):
        raise ValueError(
            f"predict needs a DataModule with a predict_dataloader, and {data_class} "
            "has none: use one that has (e.g. configs/intphys_test.yaml's), "
            "or test"
        )
    if subcommand != "fit":
        return
    interval = trainer.get("val_check_interval")
    if isinstance(interval, int) and not isinstance(interval, bool) and interval < 1:
        raise ValueError(
            f"trainer.val_check_interval {interval}: give a number of training steps >= 1 "
            "between validations, a fraction of an epoch in (0.0, 1.0], or a duration "
            "'DD:HH:MM:SS'"
        )
    if (
        isinstance(interval, int)
        and isinstance(max_steps, int)
        and max_steps > 0
        and interval > max_steps
        and _callback_configured(trainer, "VOEProbeCallback")
    ):
        rank_zero_warn(
            f"trainer.val_check_interval {interval} is larger than trainer.max_steps "
            f"{max_steps}: no validation will run, so VOEProbeCallback logs no VOE "
            f"statistics; use val_check_interval <= {max_steps} to have them"
        )
    _check_batch_size(data)


def _check_image_size(model: Any, data: Any) -> None:
    """The model's ``image_size`` (the object-state model's pixel encoder: ``frame_size``) must
    be the data's height and width (found otherwise only after the whole dataset is rendered)."""
    height, width = data.get("height"), data.get("width")
    if height is None or width is None:
        return
    for name in ("image_size", "frame_size"):
        size = model.get(name)
        if size is not None and tuple(size) != (height, width):
            raise ValueError(
                f"model.init_args.{name} {list(size)} differs from the data's height x width "
                f"{height} x {width}: set both to one size (e.g. --data.init_args.height "
                f"{size[0]} --data.init_args.width {size[1]})"
            )


def _check_batch_size(data: Any) -> None:
    """Refuse a training batch larger than the training set: dropped whole (drop_last)."""
    batch_size, examples = data.get("batch_size"), data.get("train_examples")
    if not isinstance(batch_size, int) or not isinstance(examples, int):
        return
    controls = data.get("train_controls")
    controls = examples if controls is None else controls
    concepts = concepts_of(data) or specs.CONCEPTS
    clips = (examples + controls) * len(concepts)
    if batch_size > clips:
        raise ValueError(
            f"data.init_args.batch_size {batch_size} is larger than the {clips} training clips "
            f"({examples} examples + {controls} controls x {len(concepts)} concept(s)), so "
            f"every batch would be dropped and nothing trained: use batch_size <= {clips}"
        )


def _predicts(class_path: str) -> bool:
    """Whether the DataModule class ``class_path`` names implements predict_dataloader."""
    data_class = import_object(class_path)
    return data_class.predict_dataloader is not L.LightningDataModule.predict_dataloader


def _callback_configured(trainer: Any, name: str) -> bool:
    """Whether a callback whose class is named ``name`` is among the trainer's callbacks."""
    return any(
        str(getattr(callback, "class_path", "")).rsplit(".", 1)[-1] == name
        for callback in trainer.get("callbacks") or []
    )
