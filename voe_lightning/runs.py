"""Where a run's checkpoints and reports are: ``--ckpt_path`` resolved to one checkpoint file
(``last``/``best`` to the newest run of a logger name, a directory refused naming the files in
it), and the one report folder each (checkpoint, data root, concepts, evaluation-only model
arguments) gets inside a run; and a run's record kept: a resumed ``fit`` trains on the data
and model its saved config names (``record_differences``), configs are never overwritten
(``fresh_config_name``) nor written through a link out of the run folder (``RunConfig``); and
the configs shipped in the package, whose ``base.yaml`` every run starts from and whose
``alpha`` is the default significance level of every command (``base_alpha``)."""

from __future__ import annotations

import hashlib
import pickle
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import torch
import yaml
from lightning.pytorch.cli import SaveConfigCallback

from voe_lightning.stats import statistics

#: The configs shipped inside the package (``configs/`` in a checkout links to them), found
#: wherever the package is installed.
SHIPPED_CONFIGS = Path(__file__).resolve().parent / "configs"
#: Trainer, logger, callbacks and model class every fit/validate/test/predict starts from, so
#: ``--config configs/joint.yaml`` alone is a whole run; later ``--config`` files override it.
BASE_CONFIG = SHIPPED_CONFIGS / "base.yaml"

#: ``--ckpt_path`` words that name a checkpoint of the newest run of the config's logger name.
RUN_CHECKPOINT_WORDS = ("last", "best")
#: ``--ckpt_path`` words Lightning resolves itself (a SLURM requeue's, a model registry's).
LIGHTNING_CHECKPOINT_WORDS = ("hpc", "registry")
#: The file ModelCheckpoint(save_last=True), FinalStepCheckpoint and InterruptCheckpoint write.
LAST_CHECKPOINT = "last.ckpt"
#: The folder, inside a test's log folder, of the same config tested untrained (``priors_alone``).
UNTRAINED_FOLDER = "priors_alone"


def trained_reports(run_dir: str | Path, name: str = "summary.json") -> list[Path]:
    """Every report file ``voe_report/<name>`` under ``run_dir``, oldest first, leaving out the
    reports of an untrained copy (``UNTRAINED_FOLDER``), which are no result of the run."""
    reports = [
        path
        for path in Path(run_dir).rglob(f"voe_report/{name}")
        if UNTRAINED_FOLDER not in path.relative_to(run_dir).parts
    ]
    return sorted(reports, key=lambda path: path.stat().st_mtime)


def checkpoint_file(ckpt_path: str) -> Path:
    """``ckpt_path`` as an existing checkpoint file; a directory is refused naming the
    checkpoints found under it, a missing path naming itself."""
    path = Path(ckpt_path)
    if path.is_dir():
        found = sorted(path.rglob("*.ckpt"), key=lambda file: file.stat().st_mtime)
        listed = ", ".join(str(file) for file in found[-3:][::-1])
        hint = f"the newest under it: {listed}" if found else "it holds no *.ckpt file"
        raise IsADirectoryError(
            f"--ckpt_path {ckpt_path} is a directory, not a checkpoint file; "
            f"give one .ckpt file ({hint})"
        )
    if not path.is_file():
        raise FileNotFoundError(
            f"--ckpt_path {ckpt_path!r} does not exist (give a .ckpt file, last/best for "
            "the newest run of the config's logger name, or a shipped checkpoint's name: "
            "voe_lightning.shipped.SHIPPED)"
        )
    return path


def run_checkpoint(word: str, save_dir: str | Path, name: str) -> Path:
    """The checkpoint ``word`` (``last`` or ``best``) names: of the newest run under
    ``save_dir/name`` holding a last.ckpt, that file, or the best one its ModelCheckpoint
    recorded. Refused, naming what was looked for, where there is none (Lightning would start
    ``fit`` from scratch and ``test`` untrained weights)."""
    pattern = f"*/checkpoints/{LAST_CHECKPOINT}"
    runs = sorted((Path(save_dir) / name).glob(pattern), key=lambda file: file.stat().st_mtime)
    if not runs:
        raise FileNotFoundError(
            f"--ckpt_path {word}: no checkpoint of logger name {name!r}: looked for "
            f"{Path(save_dir) / name / pattern}. Give a .ckpt file, or the logger name "
            "(--trainer.logger.init_args.name) of a trained run"
        )
    last = runs[-1]
    if word == "last":
        return last
    states = read_checkpoint(last).get("callbacks") or {}
    monitored = [
        state for state in states.values() if isinstance(state, dict) and state.get("monitor")
    ]
    if not monitored:
        raise ValueError(
            f"--ckpt_path best: the checkpoints of {last.parent} monitor no metric "
            "(ModelCheckpoint monitor is None), so none is best; give --ckpt_path last or a "
            ".ckpt file"
        )
    best = Path(monitored[0].get("best_model_path") or "")
    for candidate in (best, last.parent / best.name):
        if best.name and candidate.is_file():
            return candidate
    raise FileNotFoundError(
        f"--ckpt_path best: {last} records the best checkpoint as "
        f"{str(best) or 'none'}, which does not exist"
    )


#: How torch names the class or function a weights-only load met in a checkpoint's pickle.
PICKLED_OBJECT = re.compile(r"Unsupported global: GLOBAL (\S+)")


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """``torch.load`` of a checkpoint (weights only), naming the file when it cannot be read
    (torch's errors for a truncated file, e.g. ``OSError: [Errno 22]``, name none), and the
    object it holds where that is why (``PICKLED_OBJECT``), which is no damage."""
    try:
        checkpoint: dict[str, Any] = torch.load(path, map_location="cpu", weights_only=True)
        return checkpoint
    except PermissionError:
        raise  # names the file already
    except (OSError, EOFError, RuntimeError, pickle.UnpicklingError) as error:
        pickled = PICKLED_OBJECT.search(str(error))
        if pickled:
            raise ValueError(
                f"cannot read the checkpoint {path}: it holds a pickled object ({pickled[1]}), "
                "which loading weights only refuses, as unpickling it could run any code (this "
                "package's checkpoints hold none); if you trust the file, load it with "
                "torch.load(path, weights_only=False) and save it again without that object"
            ) from error
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(
            f"cannot read the checkpoint {path}: it is truncated or corrupt ({reason})"
        ) from error


def concepts_of(data_arguments: Any) -> tuple[str, ...] | None:
    """The concepts a DataModule's init arguments select (``concept`` or ``concepts``), in
    sorted order; None when they name none (the DataModule's default)."""
    if not data_arguments:
        return None
    concepts = data_arguments.get("concepts")
    if concepts is None and data_arguments.get("concept") is not None:
        concepts = [data_arguments.get("concept")]
    return tuple(sorted(str(concept) for concept in concepts)) if concepts is not None else None


def report_folder(
    checkpoint: Path,
    root: Path | None,
    concepts: Iterable[str] | None,
    benchmark: str | None,
    trained_root: Path | None,
    trained_concepts: Iterable[str] | None,
    evaluation: Mapping[str, Any] | None = None,
    split: str = "test",
) -> str | None:
    """The folder, inside a checkpoint's run, of the logs and report of one (checkpoint, data
    root, concepts, benchmark, ``evaluation``: the evaluation-only model arguments given
    otherwise than the checkpoint's, name -> value; the probe ``split`` reported on); None for
    the run's own (its last.ckpt on the data and concepts it was trained on, scored as
    trained, on its test probes), which goes into the run
    itself. Any other gets a folder of its own, named for people (what differs) and, so no
    two ever share one (``alt/one`` and ``alt_one``, ``a/b`` and ``/a/b``), a hash of the
    resolved checkpoint, root, concepts and evaluation-only arguments."""
    concepts = tuple(sorted(concepts)) if concepts is not None else None
    trained_concepts = tuple(sorted(trained_concepts)) if trained_concepts is not None else None
    other_root = root is not None and (
        trained_root is None or Path(root).resolve() != Path(trained_root).resolve()
    )
    other_concepts = concepts is not None and concepts != trained_concepts
    parts = [benchmark] if benchmark else []
    if checkpoint.name != LAST_CHECKPOINT:
        parts.append(f"ckpt_{checkpoint.stem}")
    if other_root:
        assert root is not None  # other_root says so
        parts.append(
            "data_" + "_".join(part for part in Path(root).parts if part not in ("/", "..", "."))
        )
    if other_concepts:
        assert concepts is not None  # other_concepts says so
        parts.append("concepts_" + "+".join(concepts))
    if split != "test":
        parts.append(f"{split}_probes")
    scored = [f"{name}_{value}" for name, value in sorted((evaluation or {}).items())]
    parts += scored
    if not parts:
        return None
    key = "\n".join(
        [
            str(checkpoint.resolve()),
            str(Path(root).resolve()) if root else "",
            ",".join(concepts or ()),
            benchmark or "",
            *scored,
            *([split] if split != "test" else []),
        ]
    )
    readable = re.sub(r"[^A-Za-z0-9_.+=-]", "_", "-".join(parts))[:80]
    return f"{readable}-{hashlib.sha256(key.encode()).hexdigest()[:8]}"


#: The training config LightningCLI saves into a run folder: the run's record.
RUN_CONFIG = "config.yaml"
#: The sections of its saved config a resumed ``fit`` must keep: what the run trains on. (Its
#: model's arguments are the checkpoint's, and one given otherwise is refused by the CLI's
#: ``parse_arguments``; the saved config holds some the model derives, as None.)
RECORD_SECTIONS = ("data",)


def record_differences(run_config: Path, given: Mapping[str, Any]) -> list[str]:
    """'key: the run trained with X, given Y' for each value of ``RECORD_SECTIONS`` in the
    ``given`` config (a plain dict, as saved) that the run's saved ``run_config`` holds
    otherwise, by dotted key; none where the run saved no readable config. A key the record
    lacks is an argument added since the run was saved (a DataModule's ``seed_offset``), which
    it ran without, and is not compared."""
    try:
        saved = yaml.safe_load(run_config.read_text())
    except (OSError, yaml.YAMLError):
        return []
    if not isinstance(saved, dict):
        return []
    old = {
        key: value
        for section in RECORD_SECTIONS
        for key, value in _flat(saved.get(section), section).items()
    }
    new = {
        key: value
        for section in RECORD_SECTIONS
        for key, value in _flat(given.get(section), section).items()
    }
    return [
        f"{key}: the run trained with {old.get(key)!r}, given {new.get(key)!r}"
        for key in sorted(old)
        if old[key] != new.get(key)
    ]


def _flat(value: Any, prefix: str) -> dict[str, Any]:
    """A nested dict's leaves by dotted key (tuples as lists: a value as YAML holds it)."""
    if isinstance(value, Mapping):
        return {
            key: leaf
            for name, item in value.items()
            for key, leaf in _flat(item, f"{prefix}.{name}").items()
        }
    return {prefix: list(value) if isinstance(value, tuple) else value}


def fresh_config_name(run_dir: Path, stem: str) -> str:
    """``<stem>.yaml``, or ``<stem>-2.yaml``, ``-3``... the first name no file in ``run_dir``
    has: a run's configs are never overwritten."""
    name, number = f"{stem}.yaml", 1
    while (run_dir / name).exists() or (run_dir / name).is_symlink():
        number += 1
        name = f"{stem}-{number}.yaml"
    return name


def check_inside(path: Path, folder: Path) -> None:
    """Refuse to write ``path`` through a symbolic link that leads out of ``folder`` (a link
    in a run folder would have the run overwrite a file elsewhere)."""
    if path.is_symlink() and not path.resolve().is_relative_to(folder.resolve()):
        raise ValueError(
            f"{path} is a symbolic link to {path.resolve()}, outside the run folder "
            f"{folder}: nothing is written through it; remove the link"
        )


class RunConfig(SaveConfigCallback):
    """LightningCLI's ``SaveConfigCallback`` that writes nothing through a symbolic link out
    of the run folder (``check_inside``) and, with ``keep_earlier`` (``validate``, ``test``,
    ``predict``), never over an earlier run's config of its name: a re-test saves
    ``test_config-2.yaml`` beside the first test's ``test_config.yaml``
    (``fresh_config_name``), so the record of what each evaluation was given is kept while
    its report is replaced; ``config_path`` is the file written (None before ``setup``)."""

    def __init__(self, *args: Any, keep_earlier: bool = False, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.keep_earlier = keep_earlier
        self.config_path: Path | None = None

    def setup(self, trainer: Any, pl_module: Any, stage: str) -> None:
        if self.save_to_log_dir and not self.already_saved:
            log_dir = Path(trainer.log_dir)  # broadcasts: every rank asks
            if self.keep_earlier:  # rank zero's folder is the one written: its free name
                name = fresh_config_name(log_dir, Path(self.config_filename).stem)
                self.config_filename = trainer.strategy.broadcast(name)
            check_inside(log_dir / self.config_filename, log_dir)
            self.config_path = log_dir / self.config_filename
        super().setup(trainer, pl_module, stage)


def base_alpha() -> float:
    """The ``alpha`` of configs/base.yaml, the one home of the default significance level:
    every run's and every command's beside Lightning's."""
    try:
        return statistics.check_alpha(yaml.safe_load(BASE_CONFIG.read_text()).get("alpha"))
    except ValueError as error:
        raise ValueError(f"{BASE_CONFIG}: {error}") from None
