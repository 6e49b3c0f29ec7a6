"""Has an object-state learner learned how things move? Two measures of the state it predicts
(the most probable Gaussian's mean, which a hidden object's belief follows):

- one step ahead, for every object seen at t-2, t-1 and t that moved more than 3 cm from t-1
  to t, on every fifth training clip of three concepts: the mean length of the true move, of
  the predicted move and of their difference, and the cosine between the two;
- at the frame a hidden object is seen again, in the physical videos of the validation probes
  of two halves (continuity's ball behind a pillar; containment's cube fallen behind the
  container): the true move since it was last seen and the predicted one.

A learner that predicts "nothing moves" scores a predicted move near 0 and a cosine near 0.

    python experiments/motion_learned.py runs/nothing_given/version_0/checkpoints/last.ckpt
"""

import argparse

import torch
from torch.utils.data import Subset

from voe_lightning import specs
from voe_lightning.data.store import open_split, record_loader
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.object_state.state import POSITION

#: Training clips whose moving objects are measured one step ahead.
CONCEPTS = ("continuity", "containment", "solidity")
#: Probe halves whose hidden objects are measured where they are seen again.
HALVES = (("continuity", "standard"), ("containment", "counterbalanced"))
MOVING = 0.03  # metres between two frames


def one_step(model: ObjectStateModel, root: str, concept: str) -> dict[str, float]:
    """The moving seen objects' true and predicted moves, one step ahead (module docstring)."""
    clips = open_split(root, concept, "train")
    true, predicted = [], []
    for batch in record_loader(Subset(clips, range(0, len(clips), 5)), 100, 0):
        with torch.no_grad():
            observations = model._inputs(None, batch["objects"], batch["camera"])
            out = model.rollout(observations)
        seen = observations.visible
        position = observations.state[..., POSITION]
        steady = seen[:, 2:] & seen[:, 1:-1] & seen[:, :-2]
        move = position[:, 2:] - position[:, 1:-1]
        guess = out["predicted"][:, 2:, :, POSITION] - position[:, 1:-1]
        moving = steady & (move.norm(dim=-1) > MOVING)
        true.append(move[moving])
        predicted.append(guess[moving])
    return _compare(torch.cat(true), torch.cat(predicted))


def at_reappearance(model: ObjectStateModel, root: str, concept: str, variant: str) -> dict:
    """Per physical probe video of the half, each object's first reappearance after being
    hidden: its true move since last seen, against the predicted one (module docstring)."""
    true, predicted, hidden = [], [], []
    for record in open_split(root, concept, "val"):
        if specs.VARIANTS[int(record["variant"])] != variant:
            continue
        video = record["consistent"]
        with torch.no_grad():
            observations = model._inputs(None, video["objects"][None], record["camera"][None])
            out = model.rollout(observations)
        seen = observations.visible[0]
        position = observations.state[0, ..., POSITION]
        for slot in range(seen.shape[1]):
            frames = seen[:, slot].nonzero().flatten().tolist()
            gaps = [(a, b) for a, b in zip(frames, frames[1:]) if b > a + 1]
            if gaps:
                last, back = gaps[0]
                true.append(position[back, slot] - position[last, slot])
                predicted.append(out["predicted"][0, back, slot, POSITION] - position[last, slot])
                hidden.append(back - last - 1)
    result = _compare(torch.stack(true), torch.stack(predicted))
    return {**result, "hidden_frames": sum(hidden) / len(hidden)}


def _compare(true: torch.Tensor, predicted: torch.Tensor) -> dict[str, float]:
    cosine = torch.nn.functional.cosine_similarity(predicted, true, dim=-1)
    return {
        "n": len(true),
        "true": float(true.norm(dim=-1).mean()),
        "predicted": float(predicted.norm(dim=-1).mean()),
        "error": float((predicted - true).norm(dim=-1).mean()),
        "cosine": float(cosine.mean()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--root", default="data/cpu")
    args = parser.parse_args()
    model = ObjectStateModel.load_from_checkpoint(args.checkpoint, map_location="cpu").eval()
    print(
        "| one step ahead, training clips | moves | true (m) | predicted (m) | error (m) | cosine |"
    )
    print("|---|---|---|---|---|---|")
    for concept in CONCEPTS:
        r = one_step(model, args.root, concept)
        print(
            f"| {concept} | {r['n']} | {r['true']:.3f} | {r['predicted']:.3f} | "
            f"{r['error']:.3f} | {r['cosine']:.2f} |"
        )
    print(
        "\n| seen again, physical probe videos | objects | frames hidden | true (m) | predicted (m) | error (m) |"
    )
    print("|---|---|---|---|---|---|")
    for concept, variant in HALVES:
        r = at_reappearance(model, args.root, concept, variant)
        print(
            f"| {concept}, {variant} | {r['n']} | {r['hidden_frames']:.1f} | {r['true']:.3f} | "
            f"{r['predicted']:.3f} | {r['error']:.3f} |"
        )


if __name__ == "__main__":
    main()
