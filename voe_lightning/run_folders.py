"""Where a run works: the checkpoint file ``--ckpt_path`` names (``last``/``best`` of the newest
run too), and the logger pointed at that checkpoint's run folder
(``<save_dir>/<name>/<version>/``), whatever logger name the config gives: a resumed ``fit``
continues there, keeping the run's record; ``validate``/``test``/``predict`` write beside the
checkpoint, in a folder of their own (``runs.report_folder``) unless they evaluate the run's own
last.ckpt on its training data and concepts. The run folder is checked creatable before any work
(``check_run_folder``). ``config`` is a Lightning subcommand's parsed config, its logger's
arguments changed in place."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import yaml
from lightning.pytorch.utilities import rank_zero_warn

from voe_lightning import runs, shipped
from voe_lightning.class_paths import import_object
from voe_lightning.data.store import store_root
from voe_lightning.probe_datamodule import ProbeDataModule

#: The longest file or folder name (bytes) common file systems take.
NAME_MAX = 255
#: Data arguments that say how the data is loaded, never which: a resumed ``fit`` may change
#: them (DataLoader workers, rendering processes, probe pairs scored at once).
LOADING_ONLY = ("num_workers", "generate_workers", "probe_batch_size")


def checkpoint_file(config: Any, ckpt_path: str) -> Path:
    """The checkpoint file ``--ckpt_path`` names: ``last``/``best`` of the newest run of
    the config's logger name (``runs.run_checkpoint``), a shipped checkpoint's run folder under
    the logger's save_dir (``shipped.unpack``), else the file itself."""
    init_args = getattr(config["trainer"].get("logger"), "init_args", None) or {}
    if ckpt_path in shipped.SHIPPED:
        return shipped.unpack(ckpt_path, init_args.get("save_dir") or "runs")
    if ckpt_path not in runs.RUN_CHECKPOINT_WORDS:
        return runs.checkpoint_file(ckpt_path)
    if not init_args.get("save_dir") or not init_args.get("name"):
        raise ValueError(
            f"--ckpt_path {ckpt_path} names the newest run of the logger's "
            "save_dir and name, and the config's trainer.logger has none: give "
            "a .ckpt file"
        )
    return runs.run_checkpoint(ckpt_path, init_args["save_dir"], init_args["name"])


def log_into_run(
    subcommand: str | None,
    config: Any,
    evaluation: dict[str, Any],
    keep_record: Callable[[Path, Path], None],
) -> None:
    """Where ``--ckpt_path`` (an existing file, resolved) lies in a run's ``checkpoints/``,
    point a logger with save_dir/name/version (TensorBoard, CSV) at that run, and for
    ``validate``/``test``/``predict`` at the folder ``runs.report_folder`` gives this
    checkpoint, data root, concepts, benchmark and ``evaluation``-only model arguments there;
    a ``fit`` resuming the run first calls ``keep_record(checkpoint, run)``."""
    ckpt_path = config.get("ckpt_path")
    if not ckpt_path or ckpt_path in runs.LIGHTNING_CHECKPOINT_WORDS:
        return
    checkpoint = Path(ckpt_path)
    init_args = getattr(config["trainer"].get("logger"), "init_args", None)
    if checkpoint.parent.name != "checkpoints" or init_args is None:
        return
    if not all(key in init_args for key in ("save_dir", "name", "version")):
        return
    run_dir = checkpoint.parent.parent
    version: str | None = run_dir.name
    if subcommand == "fit" and config.get("branch"):
        print(
            f"fit --branch: continues from {checkpoint} in a new version of "
            f"{run_dir.parent} (the run {run_dir} and its record are kept as they are)"
        )
        version = None  # the logger's next version
    elif subcommand == "fit":
        keep_record(checkpoint, run_dir)
    if (
        subcommand == "fit"
        and not config.get("branch")
        and init_args.get("name") not in (None, run_dir.parent.name)
    ):
        rank_zero_warn(
            f"fit --ckpt_path resumes in the checkpoint's run {run_dir}, so its curves and "
            f"checkpoints continue there; the logger name {init_args['name']!r} is not "
            "used. A later test of this run replaces its voe_report/: copy it first to keep it."
        )
    folder = _report_folder(config, checkpoint, evaluation) if subcommand != "fit" else None
    if folder is not None:
        version = f"{version}/{folder}"
        print(
            f"{subcommand} of {checkpoint} on other data, concepts or another "
            f"checkpoint than the run's own, or scored otherwise: its logs and report go "
            f"to {run_dir / folder}, and the run's own voe_report/ is kept"
        )
    init_args["save_dir"] = str(run_dir.parent.parent)
    init_args["name"] = run_dir.parent.name
    init_args["version"] = version


def check_run_folder(config: Any) -> None:
    """The run folder the logger will write (its logs, checkpoints, report) must be creatable:
    a name no file system takes, or a folder this user cannot write, is refused now rather
    than after training or the whole test pass."""
    logger = getattr((config.get("trainer") or {}).get("logger"), "init_args", None) or {}
    if not logger.get("save_dir"):
        return
    parts = [
        str(part) for part in (logger.get("name"), logger.get("version")) if part not in (None, "")
    ]
    for part in "/".join(parts).split("/"):
        if len(part.encode()) > NAME_MAX:
            raise ValueError(
                f"trainer.logger.init_args name or version {part[:40]}... is "
                f"{len(part.encode())} bytes long; a folder name may have at most "
                f"{NAME_MAX}: choose a shorter one"
            )
    folder = Path(logger["save_dir"], *parts)
    existing = next(path for path in (folder, *folder.parents) if path.exists())
    if not os.access(existing, os.W_OK | os.X_OK) or not existing.is_dir():
        problem = f"cannot write the run folder {folder}: {existing} is not a writable folder"
        checkpoint = _checkpoint_in_run(config, logger)
        if checkpoint is not None:  # log_into_run put the logger there
            raise PermissionError(
                f"{problem}; a checkpoint in a run's checkpoints/ folder ({checkpoint}) logs "
                f"and reports into its run {checkpoint.parent.parent}, whatever save_dir is: "
                f"make {existing} writable, or copy the checkpoint out of checkpoints/ (cp "
                f"{checkpoint} model.ckpt; --ckpt_path model.ckpt) to write under "
                "trainer.logger.init_args.save_dir"
            )
        raise PermissionError(
            f"{problem}; choose another trainer.logger.init_args.save_dir or make it writable"
        )


def _checkpoint_in_run(config: Any, logger: Any) -> Path | None:
    """``--ckpt_path`` when it lies in ``<save_dir>/<name>/<version>/checkpoints/`` and the
    logger writes into that run (``log_into_run``), else None."""
    ckpt_path = config.get("ckpt_path")
    if not ckpt_path or Path(ckpt_path).parent.name != "checkpoints":
        return None
    checkpoint = Path(ckpt_path)
    run = checkpoint.parent.parent
    if Path(logger["save_dir"], str(logger.get("name"))) != run.parent:
        return None
    return checkpoint


def resumed_config_name(
    checkpoint: Path, run_dir: Path, given: Mapping[str, Any], step: int | None
) -> str:
    """The name a ``fit`` resuming ``run_dir`` saves its config under, beside the run's
    record, never over it (``config_resumed_step<N>.yaml``); it trains on the record's data
    (its saved config.yaml), so ``given`` data that differs is refused, naming both values
    (``LOADING_ONLY`` arguments may differ)."""
    differences = [
        difference
        for difference in runs.record_differences(run_dir / runs.RUN_CONFIG, given)
        if difference.split(":")[0].rpartition(".")[2] not in LOADING_ONLY
    ]
    if differences:
        raise ValueError(
            f"fit --ckpt_path {checkpoint} resumes the run {run_dir}, which trained on other "
            f"data than given: {'; '.join(differences)}. Resume with the run's values, "
            "or add --branch true to continue from it in a new version"
        )
    return runs.fresh_config_name(
        run_dir, "config_resumed" + ("" if step is None else f"_step{step}")
    )


def _report_folder(config: Any, checkpoint: Path, evaluation: dict[str, Any]) -> str | None:
    """``runs.report_folder`` of evaluating ``checkpoint`` with ``config``'s data and the
    ``evaluation``-only model arguments given otherwise, compared with the data and concepts
    of the run's training config (``<run>/config.yaml``)."""
    data = config.get("data")
    data_args = getattr(data, "init_args", None) or {}
    data_class = import_object(data.class_path) if getattr(data, "class_path", None) else None
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
        store_root(data_args),
        runs.concepts_of(data_args),
        benchmark,
        store_root(trained_args),
        runs.concepts_of(trained_args),
        evaluation,
        data_args.get("test_split") or "test",
    )
