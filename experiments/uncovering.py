"""Does a trained object-state learner expect a hidden object to be seen again when what hides
it moves away? Per validation quadruplet half whose magic video loses an object (seen before
the manipulation frame, never after: containment's counterbalanced half, the cube that the
sliding container uncovers in the physical video; object persistence's standard half, the
object under the plank that falls flat in the magic one), from the manipulation frame on: the
learner's predicted p(seen) for that object before each frame, in each video, and the sum of
the visibility term's rectified excess over those frames. Then, on every tenth training clip of
the two concepts, the mean p(seen) it predicts for a known object at the frames it is hidden
and at those it is seen: whether it has learned when things are hidden at all.

    python experiments/uncovering.py runs/learned_states/version_0/checkpoints/last.ckpt
"""

import argparse

import numpy as np
import torch
from torch.utils.data import Subset

from voe_lightning import specs
from voe_lightning.data.store import open_split, record_loader
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.likelihood import rectified_excess

#: The halves looked at: (concept, variant), the first video of each pair the physical one.
HALVES = (("containment", "counterbalanced"), ("object_persistence", "standard"))


def seen_and_expected(model: ObjectStateModel, video, camera) -> tuple[torch.Tensor, ...]:
    """Per frame and mask id [T, K]: whether the id is seen, its predicted p(seen) before the
    frame, and the visibility term's rectified excess (0 for an id with no slot)."""
    with torch.no_grad():
        observations = model._inputs(video["frames"][None], video["objects"][None], camera[None])
        out = model.rollout(observations)
    ids = observations.ids[0]  # [S]: the mask id of each slot
    count = video["objects"]["visible_fraction"].shape[-1]
    probability = torch.zeros(out["known"].shape[1], count)
    excess = torch.zeros_like(probability)
    probability[:, ids] = out["visible_probability"][0]
    excess[:, ids] = rectified_excess(out["visibility"], out["visibility_entropy"])[0]
    return video["objects"]["visible_fraction"] > 0, probability, excess


def on_training_clips(model: ObjectStateModel, root: str, concept: str) -> tuple[float, ...]:
    """Over every tenth training clip of ``concept``: the known object-frames hidden, and the
    mean p(seen) predicted for them and for the known object-frames seen."""
    clips = open_split(root, concept, "train")
    hidden, seen = [], []
    for batch in record_loader(Subset(clips, range(0, len(clips), 10)), 100, 0):
        with torch.no_grad():
            observations = model._inputs(None, batch["objects"], batch["camera"])
            out = model.rollout(observations)
        probability = out["visible_probability"][:, 1:]
        known = out["known"][:, :-1]  # known before the frame
        visible = observations.visible[:, 1:]
        hidden.append(probability[known & ~visible])
        seen.append(probability[known & visible])
    hidden_p, seen_p = torch.cat(hidden), torch.cat(seen)
    return len(hidden_p), float(hidden_p.mean()), float(seen_p.mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--root", default="data/cpu")
    args = parser.parse_args()
    model = ObjectStateModel.load_from_checkpoint(args.checkpoint, map_location="cpu").eval()
    print(
        "| concept, half | quadruplets | frames | p(seen), physical | p(seen), magic | "
        "visibility excess, physical | magic |"
    )
    print("|---|---|---|---|---|---|---|")
    for concept, variant in HALVES:
        values: dict[str, list[float]] = {}
        quadruplets = 0
        for record in open_split(args.root, concept, "val"):
            if specs.VARIANTS[int(record["variant"])] != variant:
                continue
            physical = seen_and_expected(model, record["consistent"], record["camera"])
            magic = seen_and_expected(model, record["inconsistent"], record["camera"])
            start = int(record["manipulation_frame"])
            lost = magic[0][:start].any(0) & ~magic[0][start:].any(0)  # [K]
            lost[0] = False  # id 0: the background
            if not lost.any():
                continue
            quadruplets += 1
            for name, video in (("physical", physical), ("magic", magic)):
                after = video[1][start:, lost], video[2][start:, lost]
                values.setdefault(f"p_{name}", []).extend(after[0].flatten().tolist())
                values.setdefault(f"excess_{name}", []).append(float(after[1].sum()))
        if not quadruplets:
            print(f"| {concept}, {variant} | 0 | | | | | |")
            continue
        frames = len(values["p_physical"])
        print(
            f"| {concept}, {variant} | {quadruplets} | {frames} | "
            f"{np.mean(values['p_physical']):.2f} | {np.mean(values['p_magic']):.2f} | "
            f"{np.mean(values['excess_physical']):+.2f} | {np.mean(values['excess_magic']):+.2f} |"
        )
    print("\n| training clips | hidden object-frames | p(seen) when hidden | p(seen) when seen |")
    print("|---|---|---|---|")
    for concept, _ in HALVES:
        frames, hidden, seen = on_training_clips(model, args.root, concept)
        print(f"| {concept} | {frames} | {hidden:.2f} | {seen:.2f} |")


if __name__ == "__main__":
    main()
