"""Does the positive control know that what falls, falls faster? In solidity's training examples
(the clips it learned from), at the frame after a block's first frame of fall: how far the block
then falls (on in free fall, or landing within the frame interval), and, per checkpoint, each
Gaussian of its mixture: the fall it predicts (the mean's change of height), its standard
deviation there and its weight, as the model gives them (after ``falling_lands``), and the
``fall_gain`` its checkpoint was trained with; then what each Gaussian's choice by hard assignment rests on, the negative
log-likelihood of each part of the seen state and -log of its weight. Seen blocks only.
(``fall_gain``, the prior this measured, was deleted: it cost object persistence.)

    python experiments/free_fall.py runs/r15_fall_s8/version_0/checkpoints/last.ckpt \
        --root data/cpu
"""

import argparse
from unittest import mock

import numpy as np
import torch

from datamodules import VOEDataModule
from voe_lightning import specs
from voe_lightning.model import ObjectStateModel, likelihood
from voe_lightning.model.likelihood import gaussian_nll
from voe_lightning.model.object_state import rollout

#: A block has landed within the interval when it fell less than this (free fall: 0.60 m).
FREE_FALL = 0.55
#: The state's parts, whose negative log-likelihood under each Gaussian is reported apart.
PARTS = {
    "position": slice(0, 3),
    "orientation": slice(3, 7),
    "size": slice(7, 10),
    "colour": slice(10, 13),
}


def part_nats(observed: torch.Tensor, means: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Each Gaussian's negative log-likelihood of each part of the seen state (``PARTS``):
    ``observed`` [..., 13], ``means`` and ``log_std`` [..., K, 13] -> [..., parts, K]."""
    return torch.stack(
        [
            gaussian_nll(observed[..., None, part], means[..., part], log_std[..., part])[0]
            for part in PARTS.values()
        ],
        -2,
    )


def predicted_falls(model: ObjectStateModel, clips) -> dict[str, np.ndarray]:
    """Per clip whose block is seen at its second frame of fall: that fall (m), and each
    Gaussian's predicted fall, standard deviation and weight there, then its negative
    log-likelihood of each part of the seen state (``PARTS``) and -log of its weight (hard
    assignment trains the Gaussian with the least sum), grouped by whether the block was still
    in free fall ("free") or landed within the interval ("landed")."""
    caught = []

    def spy(observed, means, log_std, logits, hard=False):
        caught.append((observed, means, log_std, logits))
        return nll(observed, means, log_std, logits, hard=hard)

    nll = likelihood.mixture_nll
    observations = model._inputs(clips["frames"], clips["objects"], clips.get("camera"))
    with torch.no_grad(), mock.patch.object(rollout, "mixture_nll", spy):
        model.rollout(observations)
    rows: dict[str, list] = {"free": [], "landed": []}
    for b in range(observations.state.shape[0]):
        height, seen = observations.state[b, ..., 2], observations.visible[b]
        moved = ((height[1:] - height[:-1]).abs() * seen[1:] * seen[:-1]).sum(0)
        block = int(moved.argmax())  # the slot whose seen height changes most
        falls = torch.nonzero(height[1:, block] - height[:-1, block] < -0.1)
        if len(falls) == 0:
            continue
        t = int(falls[0]) + 2  # the frame after the first frame of fall
        if t >= height.shape[0] or not seen[t - 2 : t + 1, block].all():
            continue
        seen_state, means, log_std, logits = (value[b, block] for value in caught[t - 1])
        fall = float(height[t - 1, block] - height[t, block])
        rows["free" if fall > FREE_FALL else "landed"].append(
            [
                fall,
                *(height[t - 1, block] - means[:, 2]).tolist(),
                *log_std[:, 2].exp().tolist(),
                *logits.softmax(-1).tolist(),
                *part_nats(seen_state, means, log_std).flatten().tolist(),
                *(-logits.log_softmax(-1)).tolist(),
            ]
        )
    return {key: np.array(value) for key, value in rows.items() if value}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument("--clips", type=int, default=2000, help="training clips read at most")
    args = parser.parse_args()
    torch.set_num_threads(1)
    data = VOEDataModule(
        concepts=["solidity"],
        root=args.root,
        train_examples=2000,
        val_pairs=24,
        test_pairs=200,
        generalization_pairs=100,
        batch_size=250,
        num_workers=0,
    )  # configs/cpu.yaml's data
    data.setup("fit")
    torch.manual_seed(0)
    batches, read = [], 0
    for clips in data.train_dataloader():
        batches.append(clips[clips["kind"] == specs.CLIP_KINDS.index("example")])
        read += clips.shape[0]
        if read >= args.clips:
            break
    for checkpoint in args.checkpoints:
        model = ObjectStateModel.load_from_checkpoint(checkpoint, map_location="cpu").eval()
        k = model.hparams.components
        print(f"{checkpoint}: fall_gain {model.hparams.get('fall_gain', 0.0)} m")
        falls = [predicted_falls(model, clips) for clips in batches]
        for key in ("free", "landed"):
            rows = np.concatenate([f[key] for f in falls if key in f])
            r = rows.mean(0)
            print(
                f"  {key}: {len(rows)} blocks fell {r[0]:.3f} m (least {rows[:, 0].min():.3f});"
                f" per Gaussian (stop, move..., "
                f"land) predicted fall {np.round(r[1 : 1 + k], 3).tolist()}, SD "
                f"{np.round(r[1 + k : 1 + 2 * k], 3).tolist()}, weight "
                f"{np.round(r[1 + 2 * k : 1 + 3 * k], 2).tolist()}"
            )
            costs = r[1 + 3 * k :].reshape(len(PARTS) + 1, k)
            for name, cost in zip([*PARTS, "-log weight"], costs):
                print(f"    {name:12s} nats per Gaussian {np.round(cost, 2).tolist()}")


if __name__ == "__main__":
    main()
