"""Checkpoints that ship with the package, by name: ``test --ckpt_path <name>`` re-tests a
README row on any seed offset without training (issue 72). Each is the model's weights and
hyper-parameters only (no optimizer state), loadable with ``weights_only``, beside the config
its run saved; a run folder ``<save_dir>/shipped/<name>/`` is made from them on first use, so
reports land where any run's do."""

from __future__ import annotations

import hashlib
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from voe_lightning import runs

#: Where the shipped files live inside the installed package.
FOLDER = Path(__file__).parent / "checkpoints"
#: The logger name, under the config's save_dir, of the run folders made from them.
RUN_NAME = "shipped"
#: The checkpoint keys kept: what ``test`` restores and what ``--ckpt_path`` checks.
KEPT_KEYS = (
    "state_dict",
    "hyper_parameters",
    "hparams_name",
    "pytorch-lightning_version",
    "epoch",
    "global_step",
)


@dataclass(frozen=True)
class ShippedCheckpoint:
    """One shipped checkpoint: the config it trained with, its seed, the stimuli version it
    saw, the SHA-256 of its file (a changed file is refused, not tested) and what it is, as
    ``unpack`` says when it is used."""

    config: str
    seed: int
    generator_version: int
    sha256: str
    result: str


#: What the ceiling's shipped seeds are (``configs/oracle_states_15min.yaml``).
_CEILING = "the ceiling: oracle states, no rule, zero heads, 5,000 steps at batch 32"
_CEILING_SHA256 = (
    "c5cb928f8192da503e2fb85f5e9bb2955dcf272e0ce4ae98dde929a4692bf67f",
    "83d17081616e08c4000e0c19ce62bba6d22d5822b6f6984ab3faa83c5d9b07f4",
    "11dfe136477c139f1eee4b04e96d4905339cd0e9cbadea7307eef5cfc1afe66e",
)
#: The checkpoints behind the README's table, by name; every one trained on stimuli version 11.
SHIPPED: dict[str, ShippedCheckpoint] = {
    **{
        f"oracle_states_15min_s{seed}": ShippedCheckpoint(
            "oracle_states_15min", seed, 11, sha256, _CEILING
        )
        for seed, sha256 in enumerate(_CEILING_SHA256)
    },
    "masks_15min_s0": ShippedCheckpoint(
        "masks_15min",
        0,
        11,
        "119c7f3d86830c1c7813d8eed169a977a19d0658e80c48781fa72c829fd5f015",
        "the mask rung trained as the ceiling is (same recipe, mask measures)",
    ),
}


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _known(name: str) -> ShippedCheckpoint:
    if name not in SHIPPED:
        raise ValueError(
            f"no shipped checkpoint is named {name!r}; shipped: {', '.join(sorted(SHIPPED))}"
        )
    return SHIPPED[name]


def unpack(name: str, save_dir: str | Path = "runs") -> Path:
    """The ``last.ckpt`` of the run folder ``<save_dir>/shipped/<name>/`` made from the
    shipped checkpoint ``name`` and its run's config (made once; a file differing from the
    shipped one, in the package or the folder, is refused naming it)."""
    shipped = _known(name)
    source = FOLDER / f"{name}.ckpt"
    if _sha256(source) != shipped.sha256:
        raise ValueError(f"the shipped checkpoint {source} is not the one shipped (SHA-256)")
    run_dir = Path(save_dir) / RUN_NAME / name
    checkpoint = run_dir / "checkpoints" / runs.LAST_CHECKPOINT
    if checkpoint.is_file() and _sha256(checkpoint) != shipped.sha256:
        raise ValueError(
            f"{checkpoint} differs from the shipped checkpoint {name!r}: move the folder "
            f"{run_dir} away to unpack it again"
        )
    if not checkpoint.is_file():
        checkpoint.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(FOLDER / f"{name}.yaml", run_dir / runs.RUN_CONFIG)
        shutil.copyfile(source, checkpoint)
    print(
        f"--ckpt_path {name}, shipped: {shipped.result} (configs/{shipped.config}.yaml, "
        f"seed {shipped.seed}, trained on stimuli version {shipped.generator_version}), "
        f"in {run_dir}"
    )
    return checkpoint


def pack(run_checkpoint: str | Path, name: str) -> tuple[Path, str]:
    """Write the checkpoint ``run_checkpoint`` of a run (its folder's config.yaml beside) into
    the package as ``name``, weights and hyper-parameters only; returns the file and its
    SHA-256, for its ``SHIPPED`` entry."""
    run_checkpoint = Path(run_checkpoint)
    checkpoint: dict[str, Any] = runs.read_checkpoint(run_checkpoint)
    kept = {key: checkpoint[key] for key in KEPT_KEYS if key in checkpoint}
    FOLDER.mkdir(exist_ok=True)
    target = FOLDER / f"{name}.ckpt"
    torch.save(kept, target)
    shutil.copyfile(run_checkpoint.parent.parent / runs.RUN_CONFIG, FOLDER / f"{name}.yaml")
    return target, _sha256(target)
