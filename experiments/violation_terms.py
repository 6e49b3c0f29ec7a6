"""Which of the positive control's surprise terms carries a concept's relative surprise d, and
at which frames (round eighteen): per variant of the test probes, each term's mean d and its r
with the foreground cue's difference, d per frame counted from the first frame at which an
object is seen in one video and not the other, and the r of the foreground cue with the two
videos' absolute difference of visible fractions (``visible_fraction`` is a share of the frame's
pixels, so the cue counts the violation's own object-frames in pixels).

    python experiments/violation_terms.py runs/object_state/version_0/checkpoints/last.ckpt \
        --concepts containment
"""

import argparse

import numpy as np
import torch
from scipy import stats

from voe_lightning import specs
from voe_lightning.audit import cues, video_cues
from voe_lightning.data.store import open_split
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.likelihood import rectified_excess
from voe_lightning.model.object_state.state import SLOT_TERMS

#: Frames of the per-frame profile, from the first frame the two videos part.
PROFILE = range(-2, 10)


def term_surprise(model: ObjectStateModel, video, camera) -> dict[str, np.ndarray]:
    """Each term's surprise per frame [T] of one video (rectified excess, as ``_per_frame``
    sums them)."""
    with torch.no_grad():
        out = model.rollout(
            model._inputs(video["frames"][None], video["objects"][None], camera[None])
        )
    terms = {
        name: rectified_excess(out[name], out[f"{name}_entropy"]).sum(-1)[0] for name in SLOT_TERMS
    }
    terms["appear"] = rectified_excess(out["appear"], out["appear_entropy"])[0]
    return {name: value.numpy() for name, value in terms.items()}


def pair_rows(model: ObjectStateModel, root: str, concept: str) -> dict[str, list[dict]]:
    """Per standard variant, per test pair: d per term and frame, the foreground cue's
    difference, the visible fractions' absolute difference and the first frame they part."""
    rows = {variant: [] for variant in specs.STANDARD_VARIANTS[concept]}
    for record in open_split(root, concept, "test"):
        variant = specs.VARIANTS[int(record["variant"])]
        if variant not in rows:
            continue
        m = record["manipulation_frame"].reshape(1)
        score = {
            side: video_cues.score_videos(
                record[side]["frames"][None], record[side]["mask"][None], m
            )["foreground_pixels"][0]
            for side in cues.SIDES
        }
        fraction = {side: record[side]["objects"]["visible_fraction"] for side in cues.SIDES}
        terms = {side: term_surprise(model, record[side], record["camera"]) for side in cues.SIDES}
        parted = np.flatnonzero(
            ((fraction["inconsistent"] > 0) != (fraction["consistent"] > 0)).any(-1).numpy()
        )
        rows[variant].append(
            {
                "d": {
                    name: terms["inconsistent"][name] - terms["consistent"][name]
                    for name in terms["consistent"]
                },
                "foreground": float(score["inconsistent"] - score["consistent"]),
                "fractions": float(
                    (fraction["inconsistent"] - fraction["consistent"])[int(m) + 1 :].abs().sum()
                ),
                "parted": int(parted[0]) if len(parted) else None,
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument("--concepts", nargs="+", default=["containment"], choices=specs.CONCEPTS)
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = ObjectStateModel.load_from_checkpoint(args.checkpoint, map_location="cpu").eval()
    for concept in args.concepts:
        for variant, rows in pair_rows(model, args.root, concept).items():
            foreground = np.array([row["foreground"] for row in rows])
            fractions = np.array([row["fractions"] for row in rows])
            total = np.array([sum(v.sum() for v in row["d"].values()) for row in rows])
            print(
                f"{concept} {variant} ({len(rows)} pairs): mean d {total.mean():.2f}, "
                f"r(d, foreground) {stats.pearsonr(total, foreground)[0]:+.2f}, "
                f"r(foreground, |visible fractions' difference|) "
                f"{stats.pearsonr(foreground, fractions)[0]:+.2f}"
            )
            for name in rows[0]["d"]:
                term = np.array([row["d"][name].sum() for row in rows])
                if np.ptp(term) > 0:
                    print(
                        f"  {name:15s} mean d {term.mean():8.2f}, r with foreground "
                        f"{stats.pearsonr(term, foreground)[0]:+.2f}"
                    )
            profile = [
                [
                    sum(v[row["parted"] + k] for v in row["d"].values())
                    for row in rows
                    if row["parted"] is not None and 0 <= row["parted"] + k < len(row["d"]["state"])
                ]
                for k in PROFILE
            ]
            print(
                "  mean d per frame from the first parted frame "
                f"({PROFILE.start} to {PROFILE.stop - 1}):",
                [round(float(np.mean(values)), 2) if values else None for values in profile],
            )


if __name__ == "__main__":
    main()
