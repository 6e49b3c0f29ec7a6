"""Where a run with ``--ckpt_path`` works: the checkpoint file it names (``last``/``best`` of
the newest run too), and the logger pointed at that checkpoint's run folder
(``<save_dir>/<name>/<version>/``), whatever logger name the config gives: a resumed ``fit``
continues there, keeping the run's record; ``validate``/``test``/``predict`` write beside the
checkpoint, in a folder of their own (``runs.report_folder``) unless they evaluate the run's own
last.ckpt on its training data and concepts."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
from lightning.pytorch.utilities import rank_zero_warn

from voe_lightning import runs
from voe_lightning.cli.class_paths import import_object
from voe_lightning.data.store_plan import store_root
from voe_lightning.probe_datamodule import ProbeDataModule

#: Data arguments that say how the data is loaded, never which: a resumed ``fit`` may change
#: them (DataLoader workers, rendering processes, probe pairs scored at once).
LOADING_ONLY = ("num_workers", "generate_workers", "probe_batch_size")


def checkpoint_file(config: Any, ckpt_path: str) -> Path:
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


def log_into_run(
    subcommand: str,
    config: Any,
    checkpoint: Path,
    evaluation: dict[str, Any],
    keep_record: Callable[[Path, Path], None],
) -> None:
    """Point a logger with save_dir/name/version (TensorBoard, CSV) at the checkpoint's
    run, and for ``validate``/``test``/``predict`` at the folder ``runs.report_folder``
    gives this checkpoint, data root, concepts, benchmark and ``evaluation``-only model
    arguments there; a ``fit`` resuming the run first calls ``keep_record(checkpoint, run)``."""
    init_args = getattr(config["trainer"].get("logger"), "init_args", None)
    if init_args is None or not all(key in init_args for key in ("save_dir", "name", "version")):
        return
    run_dir = checkpoint.parent.parent
    version = run_dir.name
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


def resumed_config_name(checkpoint: Path, run_dir: Path, given: dict, step: int | None) -> str:
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
