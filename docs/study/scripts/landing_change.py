"""Does the landing Gaussian's learned change cost object persistence (round eighteen, at
evaluation only)? Per checkpoint, object persistence's test pairs scored as trained and with the
landing Gaussian's learned change of position and orientation set to 0 (it then lays the object
down from where inertia takes it, by geometry alone): each variant's t of d (as ``test``
computes it), the share of pairs with d > 0, and r(d, the motion cue's difference).

    python docs/study/scripts/landing_change.py runs/r18_s4/version_0/checkpoints/last.ckpt \
        --root data/cpu
"""

import argparse

import numpy as np
import torch
from scipy import stats

from voe_lightning import cues, specs
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.object_state import STATE_SIZE
from voe_lightning.store import open_split


def without_landing_change(model: ObjectStateModel) -> torch.utils.hooks.RemovableHandle:
    """Zero the dynamics' output for the last (landing) Gaussian's change of position and
    orientation, so its mean is the geometry's alone."""
    start = (model.hparams.components - 1) * STATE_SIZE

    def hook(module, inputs, out):
        out = out.clone()
        out[..., start:start + 7] = 0.0
        return out
    return model.dynamics.register_forward_hook(hook)


def scored(model: ObjectStateModel, records: list) -> dict[str, np.ndarray]:
    """Per variant, [pairs, 2]: d (the videos' summed surprise, inconsistent less consistent)
    and the motion cue's difference."""
    rows: dict[str, list] = {}
    for record in records:
        m = record["manipulation_frame"].reshape(1)
        surprise, motion = {}, {}
        for side in cues.SIDES:
            video = record[side]
            surprise[side] = float(model.surprise(video["frames"][None], None,
                                                  record["camera"][None],
                                                  video["objects"][None]).sum())
            motion[side] = float(cues.score_videos(video["frames"][None], video["mask"][None],
                                                   m)["motion_energy"][0])
        rows.setdefault(specs.VARIANTS[int(record["variant"])], []).append(
            (surprise["inconsistent"] - surprise["consistent"],
             motion["inconsistent"] - motion["consistent"]))
    return {variant: np.array(values) for variant, values in rows.items()}


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
    for checkpoint in args.checkpoints:
        model = ObjectStateModel.load_from_checkpoint(checkpoint, map_location="cpu").eval()
        for label in ("as trained", "no landing change"):
            handle = without_landing_change(model) if label != "as trained" else None
            for variant, values in scored(model, records).items():
                d, motion = values.T
                print(f"{checkpoint} {label:17s} {variant:15s} t {stats.ttest_1samp(d, 0.0).statistic:+.2f}"
                      f" ({np.mean(d > 0):.0%}), r(d, motion) {stats.pearsonr(d, motion)[0]:+.2f}")
            if handle is not None:
                handle.remove()


if __name__ == "__main__":
    main()
