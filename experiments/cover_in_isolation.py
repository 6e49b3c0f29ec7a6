"""Can the visibility read from the states (``visibility_from: states``) learn occlusion from
what the trained learner predicts? From a checkpoint's rollouts over every fourth training clip
of containment and object persistence, the inputs of its visibility at each frame (predicted
states, pair features, known slots, pose) and what was seen; fresh in-view and cover networks
of the same shape are then trained on the first 80% of those frames alone, and the mean
p(seen) on the rest is printed for the hidden and the seen known object-frames.

    python experiments/cover_in_isolation.py runs/nothing_given/version_0/checkpoints/last.ckpt
"""

import argparse

import torch
import torch.nn.functional as F
from torch.utils.data import Subset

from voe_lightning.data.store import open_split, record_loader
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.dynamics import mlp
from voe_lightning.model.object_state.rollout import SlotRollout


def visibility_inputs(model: ObjectStateModel, root: str) -> list[tuple[torch.Tensor, ...]]:
    """Per training batch and frame t >= 1: what ``_composed_logit`` read, and ``visible``."""
    frames: list[tuple[torch.Tensor, ...]] = []
    read: list[tuple[torch.Tensor, ...]] = []
    composed = SlotRollout._composed_logit

    def recording(self, *inputs):
        read.append(inputs)
        return composed(self, *inputs)

    SlotRollout._composed_logit = recording
    try:
        for concept in ("containment", "object_persistence"):
            clips = open_split(root, concept, "train")
            for batch in record_loader(Subset(clips, range(0, len(clips), 4)), 200, 0):
                read.clear()
                with torch.no_grad():
                    observations = model._inputs(None, batch["objects"], batch["camera"])
                    model.rollout(observations)
                for t, inputs in enumerate(read, start=1):
                    frames.append((*inputs, observations.visible[:, t].float()))
    finally:
        SlotRollout._composed_logit = composed
    return frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument("--steps", type=int, default=3000)
    args = parser.parse_args()
    torch.manual_seed(0)
    model = ObjectStateModel.load_from_checkpoint(args.checkpoint, map_location="cpu").eval()
    if model.hparams.visibility_from != "states":
        raise SystemExit(f"{args.checkpoint} reads visibility from memory, not the states")
    frames = visibility_inputs(model, args.root)
    width = model.hparams.hidden_size
    model.in_view = mlp([model.in_view[0].in_features, width, 1])  # fresh, trained alone
    model.cover = mlp([model.cover[0].in_features, width, 1])
    parameters = [*model.in_view.parameters(), *model.cover.parameters()]
    optimizer = torch.optim.Adam(parameters, lr=model.hparams.learning_rate)
    train, held_out = frames[: int(0.8 * len(frames))], frames[int(0.8 * len(frames)) :]
    print("| Adam steps | held-out p(seen), hidden | seen |\n|---|---|---|")
    for step in range(1, args.steps + 1):
        *inputs, visible = train[step % len(train)]
        known = inputs[3]
        logit = model._composed_logit(*inputs)
        nll = F.binary_cross_entropy_with_logits(logit, visible, reduction="none")
        loss = (nll * known).sum() / known.sum()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if step % 1000 == 0:
            hidden, seen = [], []
            with torch.no_grad():
                for *inputs, visible in held_out:
                    known, p = inputs[3], torch.sigmoid(model._composed_logit(*inputs))
                    hidden.append(p[known & (visible == 0)])
                    seen.append(p[known & (visible == 1)])
            print(f"| {step} | {torch.cat(hidden).mean():.2f} | {torch.cat(seen).mean():.2f} |")


if __name__ == "__main__":
    main()
