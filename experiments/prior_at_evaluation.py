"""What a prior does at evaluation alone: a positive-control checkpoint's paired test of every
test variant (t and share of pairs right, ``statistics.paired_test`` as ``test`` reports it),
with constructor arguments given instead of the checkpoint's (``--set``, only ones that add no
parameter), on the test pairs of configs/cpu.yaml's data.

    python experiments/prior_at_evaluation.py \
        runs/object_state/version_0/checkpoints/last.ckpt --set pivot_landing=false
"""

import argparse

import torch
import yaml

from voe_lightning import specs
from voe_lightning.datamodules import VOEDataModule
from voe_lightning.model import ObjectStateModel
from voe_lightning.runs import base_alpha
from voe_lightning.stats import statistics
from voe_lightning.stats.surprise_window import video_surprise


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument(
        "--concepts", nargs="+", default=list(specs.CONCEPTS), choices=specs.CONCEPTS
    )
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a constructor argument to use instead of the checkpoint's",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    overrides = {
        name: yaml.safe_load(value)  # true -> True, 0.392 -> 0.392
        for name, value in (setting.split("=", 1) for setting in args.set)
    }
    model = ObjectStateModel.load_from_checkpoint(
        args.checkpoint, map_location="cpu", **overrides
    ).eval()
    data = VOEDataModule(
        concepts=args.concepts,
        root=args.root,
        train_examples=2000,
        val_pairs=24,
        test_pairs=200,
        generalization_pairs=100,
        generalization=False,
        probe_batch_size=100,
    )  # configs/cpu.yaml's data
    data.setup("test")
    surprise: dict[tuple[str, str], dict[str, list]] = {}
    with torch.no_grad():
        for batch in data.test_dataloader():
            out = model.probe_step(batch)
            for side in ("consistent", "inconsistent"):
                videos = video_surprise(out[f"surprise_{side}"])
                for concept, variant, value in zip(out["concept"], out["variant"], videos):
                    key = (specs.CONCEPTS[int(concept)], specs.VARIANTS[int(variant)])
                    surprise.setdefault(key, {}).setdefault(side, []).append(float(value))
    print(f"{args.checkpoint} with {overrides or 'its own arguments'}")
    for (concept, variant), sides in surprise.items():
        result = statistics.paired_test(
            sides["inconsistent"], sides["consistent"], bootstrap=0, alpha=base_alpha()
        )
        print(
            f"  {concept:18s} {variant:15s} n {result.n:3d}  t {result.t:+8.2f}  "
            f"right {result.accuracy:.0%}"
        )


if __name__ == "__main__":
    main()
