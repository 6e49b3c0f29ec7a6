"""Can a camera tell solidity's tall block from its short one before the hidden change? Per
validation quadruplet: the most image rows the block's mask spans in the frames before the
change in A's consistent video (tall) and in B's (short), and at the change frame itself, where
only their level tops show. If the two differ before the change, a learner of masks and depth
is given what decides the concept and must carry it in memory past the change; the oracle states
hand it the block's size at every frame instead.

    python experiments/solidity_heights.py --root data/quickstart --split val
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.data.store import open_split


def rows_spanned(mask: torch.Tensor, object_id: int) -> np.ndarray:
    """Per frame, how many image rows the id's pixels span in ``mask`` [T, H, W] (0: unseen)."""
    rows = (mask == object_id).any(-1)  # [T, H]
    first = rows.float().argmax(-1)
    last = rows.shape[-1] - 1 - rows.flip(-1).float().argmax(-1)
    return torch.where(rows.any(-1), last - first + 1, 0).numpy()


def heights(quadruplet: dict[str, TensorDict]) -> tuple[int, int, int, int]:
    """(tall before, short before, tall at the change, short at the change): rows spanned."""
    standard, counterbalanced = quadruplet["standard"], quadruplet["counterbalanced"]
    change = int(standard["manipulation_frame"])
    block = int(standard["manipulated_ids"][0])
    tall = rows_spanned(standard["consistent", "mask"], block)
    short = rows_spanned(counterbalanced["consistent", "mask"], block)
    return (
        int(tall[:change].max()),
        int(short[:change].max()),
        int(tall[change]),
        int(short[change]),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", default="data/quickstart")
    parser.add_argument("--split", default="val", choices=["val", "test"])
    args = parser.parse_args()
    pairs = open_split(args.root, "solidity", args.split)
    quadruplets: dict[int, dict[str, TensorDict]] = {}
    for index in range(len(pairs)):
        pair = pairs[index]
        variant = specs.VARIANTS[int(pair["variant"])]
        quadruplets.setdefault(int(pair["seed"]), {})[variant] = pair
    measured = np.array([heights(q) for q in quadruplets.values() if len(q) == 2])
    before, at_change = measured[:, 0] - measured[:, 1], measured[:, 2] - measured[:, 3]
    print(f"{args.root} {args.split}: {len(measured)} solidity quadruplets, image rows spanned")
    print("| | tall (A) | short (B) | tall - short: mean | min | max |")
    print("|---|---|---|---|---|---|")
    for label, tall, short, diff in (
        ("before the change (most)", measured[:, 0], measured[:, 1], before),
        ("at the change", measured[:, 2], measured[:, 3], at_change),
    ):
        print(
            f"| {label} | {tall.mean():.1f} | {short.mean():.1f} | {diff.mean():+.1f} "
            f"| {diff.min():+d} | {diff.max():+d} |"
        )


if __name__ == "__main__":
    main()
