"""Whether the RGB-D rung's depth keeps its place: its recipe (configs/rgbd_15min.yaml) trained
with the depth left out, zeroed in every state the rung reads (training clips and probes alike),
then validated on a store of validation probes. A part whose removal costs no concept on
validation is a given no measurement needs: so went the depth span (mean less least depth) and
the outline's cut share, which the rung read until this experiment found neither needed (seed 0,
version 13: 2 of 5 with both, 3 without the span, 2 without the cut share).

    python experiments/depth_ablation.py --drop mean --seed 0 --val_root data/val_probes

``--drop mean``: the mean depth, the one depth measure the rung reads (its position then holds
the image plane alone). Other arguments go to
``fit`` as they are (``--trainer.max_steps 10``). The fit logs to
runs/rgbd_no_<part>[_s<seed>]; then ``validate`` on ``--val_root`` (100 validation pairs per
variant, generated there on first use with one pair or clip of every other split) prints its
verdict table. The full rung's own table: ``validate --ckpt_path`` of its run, the same store.
"""

from __future__ import annotations

import argparse
import runpy
import sys
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import torch

from voe_lightning.model.object_state import rgbd
from voe_lightning.model.object_state.state import Observations

#: Where each part of the depth lies in an ``rgbd.RGBD`` state.
PARTS = {"mean": rgbd.RGBD.position.stop - 1}


def leave_out(part: str) -> None:
    """Make the RGB-D rung read a zero for ``part`` wherever it reads the depth."""
    column, measured_by = PARTS[part], rgbd.observe_rgbd_measured

    def without(measured: Mapping[str, torch.Tensor], camera: torch.Tensor) -> Observations:
        seen = measured_by(measured, camera)
        state = seen.state.clone()
        state[..., column] = 0.0
        return replace(seen, state=state)

    rgbd.observe_rgbd_measured = without


def cli(args: list[str]) -> None:
    """``python -m voe_lightning ARGS`` in this process, through the package's entry point, so
    that ``leave_out``'s change holds in it."""
    sys.argv = ["voe_lightning", *args]
    try:
        runpy.run_module("voe_lightning", run_name="__main__", alter_sys=True)
    except SystemExit as done:
        if done.code:
            raise


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drop", choices=sorted(PARTS), required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--config", default="configs/rgbd_15min.yaml")
    parser.add_argument("--val_root", default="data/val_probes")
    parser.add_argument("--val_pairs", type=int, default=100)
    args, fit_args = parser.parse_known_args()  # the rest go to ``fit`` as they are
    leave_out(args.drop)
    name = f"rgbd_no_{args.drop}" + (f"_s{args.seed}" if args.seed else "")
    cli(
        ["fit", "--config", args.config, "--seed_everything", str(args.seed)]
        + ["--trainer.logger.init_args.name", name, *fit_args]
    )
    checkpoint = sorted(Path("runs", name).glob("version_*/checkpoints/last.ckpt"))[-1]
    cli(
        ["validate", "--config", args.config, "--ckpt_path", str(checkpoint)]
        + ["--trainer.logger.init_args.name", f"{name}_val"]
        + [f"--data.init_args.{k}={v}" for k, v in _validation_store(args).items()]
    )


def _validation_store(args: argparse.Namespace) -> dict[str, object]:
    """The data arguments that read ``--val_root``'s validation pairs (each other split holds
    the one record the data module asks at least)."""
    return {
        "root": args.val_root,
        "val_pairs": args.val_pairs,
        "train_examples": 1,
        "test_pairs": 1,
        "generalization_pairs": 1,
        "generalization": False,
    }


if __name__ == "__main__":
    main()
