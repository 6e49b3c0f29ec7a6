"""Would a seed's likelihood pick the seeds that pass? For each positive-control checkpoint, the
negative log-likelihood (nats per video, the training loss's terms, nothing withheld) of the
consistent videos of every validation probe (physical videos it never trained on) and of 100
training clips per concept (every 40th); lower is likelier. No inconsistent video is read.

    python experiments/heldout_likelihood.py runs/r12_s*/version_0/checkpoints/last.ckpt
"""

import argparse
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Subset

from voe_lightning import specs
from voe_lightning.data.store import collate, open_split
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.base import video_inputs
from voe_lightning.model.object_state.state import SLOT_TERMS

#: Every how many training clips one is scored.
TRAIN_STRIDE = 40


def video_nll(model: ObjectStateModel, batch, side: str | None = None) -> torch.Tensor:
    """Each video's negative log-likelihood [B]: every term summed over frames and objects."""
    inputs = video_inputs(batch, side) if side else video_inputs(batch)
    frames = batch[side, "frames"] if side else batch["frames"]
    with torch.no_grad():
        out = model.rollout(model._inputs(frames, inputs.get("objects"), inputs.get("camera")))
    return sum(out[name].flatten(1).sum(1) for name in SLOT_TERMS + ("appear",))


def one_batch(dataset) -> object:
    return next(iter(DataLoader(dataset, batch_size=len(dataset), collate_fn=collate)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--root", default="data/cpu")
    args = parser.parse_args()
    torch.set_num_threads(1)
    validation = {
        concept: one_batch(open_split(args.root, concept, "val")) for concept in specs.CONCEPTS
    }
    training = {}
    for concept in specs.CONCEPTS:
        clips = open_split(args.root, concept, "train")
        training[concept] = one_batch(Subset(clips, range(0, len(clips), TRAIN_STRIDE)))
    print("| run | consistent validation videos | training clips | per concept (validation) |")
    print("|---|---|---|---|")
    for checkpoint in args.checkpoints:
        model = ObjectStateModel.load_from_checkpoint(checkpoint, map_location="cpu").eval()
        held_out = {
            concept: float(video_nll(model, batch, "consistent").mean())
            for concept, batch in validation.items()
        }
        seen = [float(video_nll(model, batch).mean()) for batch in training.values()]
        run = Path(checkpoint).parents[2].name
        per_concept = ", ".join(f"{concept} {value:.0f}" for concept, value in held_out.items())
        print(
            f"| {run} | {np.mean(list(held_out.values())):.1f} | {np.mean(seen):.1f} | "
            f"{per_concept} |"
        )


if __name__ == "__main__":
    main()
