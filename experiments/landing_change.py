"""Does the landing Gaussian's learned change cost object persistence (round eighteen, at
evaluation only)? Per checkpoint, object persistence's test pairs scored as trained and with the
landing Gaussian's learned change of position and orientation set to 0 (it then lays the object
down from where inertia takes it, by geometry alone): each variant's t of d (as ``test``
computes it), the share of pairs with d > 0, and r(d, the motion cue's difference).

    python experiments/landing_change.py runs/r18_s4/version_0/checkpoints/last.ckpt \
        --root data/cpu
"""

import argparse

import numpy as np
import torch
from scipy import stats

from voe_lightning import specs
from voe_lightning.audit import video_cues
from voe_lightning.data.store import open_split
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.object_state.state import STATE_SIZE


def without_landing_change(model: ObjectStateModel) -> torch.utils.hooks.RemovableHandle:
    """Zero the dynamics' output for the last (landing) Gaussian's change of position and
    orientation, so its mean is the geometry's alone."""
    start = (model.hparams.components - 1) * STATE_SIZE

    def hook(module, inputs, out):
        out = out.clone()
        out[..., start : start + 7] = 0.0
        return out

    return model.dynamics.register_forward_hook(hook)


def relative(records: list, score) -> np.ndarray:
    """Per pair, ``score`` of the inconsistent video less that of the consistent one."""
    return np.array(
        [score(record, "inconsistent") - score(record, "consistent") for record in records]
    )


def motion(record, side: str) -> float:
    video = record[side]
    return float(
        video_cues.score_videos(
            video["frames"][None], video["mask"][None], record["manipulation_frame"].reshape(1)
        )["motion_energy"][0]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--pairs", type=int, default=200, help="test pairs per variant")
    parser.add_argument("--root", default="data/cpu")
    args = parser.parse_args()
    torch.set_num_threads(1)
    records, count = [], dict.fromkeys(specs.STANDARD_VARIANTS["object_persistence"], 0)
    for record in open_split(args.root, "object_persistence", "test"):
        variant = specs.VARIANTS[int(record["variant"])]
        if count.get(variant, args.pairs) < args.pairs:
            count[variant] += 1
            records.append(record)
    variants = np.array([specs.VARIANTS[int(record["variant"])] for record in records])
    moved = relative(records, motion)  # the model's d is set against it, checkpoint by checkpoint
    for checkpoint in args.checkpoints:
        model = ObjectStateModel.load_from_checkpoint(checkpoint, map_location="cpu").eval()

        def surprise(record, side: str, model=model) -> float:
            video = record[side]
            return float(
                model.surprise(
                    video["frames"][None], None, record["camera"][None], video["objects"][None]
                ).sum()
            )

        for label in ("as trained", "no landing change"):
            handle = without_landing_change(model) if label != "as trained" else None
            d = relative(records, surprise)
            for variant in dict.fromkeys(variants):
                mine = variants == variant
                print(
                    f"{checkpoint} {label:17s} {variant:15s} t "
                    f"{stats.ttest_1samp(d[mine], 0.0).statistic:+.2f} ({np.mean(d[mine] > 0):.0%}),"
                    f" r(d, motion) {stats.pearsonr(d[mine], moved[mine])[0]:+.2f}"
                )
            if handle is not None:
                handle.remove()


if __name__ == "__main__":
    main()
