"""How much of a learner's quadruplet halves comes from frames where the probe's object is at the
frame's edge? Per half of a concept's validation pairs: the mean d = S(inconsistent) -
S(consistent) of an object-state learner's surprise, summed over the frames at which the
manipulated object shows in the frame's border pixels and over the others, each with its
one-sample t; and in how many pairs each video shows it at the edge in its last frame. A half
carried by the edge frames follows the object leaving the view, not the concept.

    python experiments/frame_edge.py runs/rgbd_15min/version_0/checkpoints/last.ckpt \
        --root data/val_probes --concept continuity
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np
import torch
from scipy import stats
from surprise_terms import rollout_of

from voe_lightning import specs
from voe_lightning.data.store import open_split
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.likelihood import rectified_excess
from voe_lightning.model.object_state.state import SLOT_TERMS
from voe_lightning.scenes.ball_sight import at_frame_edge


def by_frame(model: ObjectStateModel, video, camera) -> torch.Tensor:
    """One video's surprise per frame [T], every term summed over slots."""
    out = rollout_of(model, video, camera)
    per_slot = sum(rectified_excess(out[t], out[f"{t}_entropy"])[0] for t in SLOT_TERMS)
    return per_slot.sum(-1) + rectified_excess(out["appear"], out["appear_entropy"])[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--root", default="data/val_probes")
    parser.add_argument("--concept", default="continuity")
    args = parser.parse_args()
    model = ObjectStateModel.load_from_checkpoint(args.checkpoint, map_location="cpu").eval()
    d: dict[str, list[tuple[float, float]]] = defaultdict(list)
    last: dict[str, list[tuple[bool, bool]]] = defaultdict(list)
    for record in open_split(args.root, args.concept, "val"):
        variant = specs.VARIANTS[int(record["variant"])]
        if variant not in specs.VERDICT_VARIANTS[args.concept]:
            continue
        object_id = int(record["manipulated_ids"][0])
        sums, ends = [], []
        for side in ("inconsistent", "consistent"):
            video = record[side]
            edge = torch.from_numpy(at_frame_edge(video["mask"].numpy(), object_id))
            surprise = by_frame(model, video, record["camera"])
            sums.append((float(surprise[edge].sum()), float(surprise[~edge].sum())))
            ends.append(bool(edge[-1]))
        d[variant].append((sums[0][0] - sums[1][0], sums[0][1] - sums[1][1]))
        last[variant].append((ends[0], ends[1]))
    print(
        "| half | pairs | d on edge frames (t) | d on the other frames (t) | at the edge last: inconsistent, consistent |"
    )
    print("|---|---|---|---|---|")
    for variant, values in d.items():
        a, ends = np.asarray(values), np.asarray(last[variant])
        cells = [
            f"{a[:, i].mean():+.2f} ({stats.ttest_1samp(a[:, i], 0.0).statistic:.1f})"
            if a[:, i].std() > 0
            else "0"
            for i in (0, 1)
        ]
        print(
            f"| {variant} | {len(a)} | {cells[0]} | {cells[1]} | "
            f"{int(ends[:, 0].sum())}, {int(ends[:, 1].sum())} |"
        )


if __name__ == "__main__":
    main()
