"""How much of the object a probe is about does a camera show before the change? Per concept, in
the physical video of every validation probe pair (up to and including the manipulation frame),
the frames at which the manipulated object is seen at all and those at which it is seen whole
(no share of its outline cut by a nearer surface or the frame's edge: the records' depth
``cut`` measure); then, in every tenth training clip, the frames its most-moving object is seen
whole over the whole clip. What a learner on masks and depth can know of a size or a speed it
knows from such frames; an oracle's states give both whenever any of the object shows.

    python experiments/seen_wholly.py --root data/val_probes --train_root data/states_10k
"""

from __future__ import annotations

import argparse
import itertools
from collections import Counter

import torch

from voe_lightning import specs
from voe_lightning.data.store import open_split

#: Below this share of its outline cut, an object counts as seen whole.
WHOLE = 0.05


def whole_frames(video, object_id: int, last: int) -> tuple[int, int]:
    """Frames 0..``last`` at which ``object_id`` is seen, and seen whole."""
    seen = (video["mask"][: last + 1] == object_id).flatten(1).any(1)
    whole = seen & (video["depth"][: last + 1, object_id, 2] < WHOLE)
    return int(seen.sum()), int(whole.sum())


def probes(root: str, concept: str) -> tuple[Counter[int], Counter[int]]:
    """Over the physical videos of ``concept``'s validation pairs: how many show the
    manipulated object in n frames up to the change, and whole in n frames."""
    seen, whole = Counter[int](), Counter[int]()
    for record in open_split(root, concept, "val"):
        if specs.VARIANTS[int(record["variant"])] not in specs.VERDICT_VARIANTS[concept]:
            continue
        counts = whole_frames(
            record["consistent"],
            int(record["manipulated_ids"][0]),
            int(record["manipulation_frame"]),
        )
        seen[counts[0]] += 1
        whole[counts[1]] += 1
    return seen, whole


def examples(root: str, concept: str, clips: int) -> Counter[int]:
    """Over every tenth of the first ``clips`` training examples of ``concept``: how many show
    their most-moving object (by its oracle states, a label only) whole in n frames."""
    whole = Counter[int]()
    records = itertools.islice(open_split(root, concept, "train"), 0, clips, 10)
    for record in records:
        if specs.CLIP_KINDS[int(record["kind"])] != "example":
            continue
        position = record["objects"]["position"]
        moved = (position[1:] - position[:-1]).norm(dim=-1).sum(0)
        moved[0] = -1.0  # id 0 is no object
        whole[whole_frames(record, int(torch.argmax(moved)), len(position) - 1)[1]] += 1
    return whole


def share(counts: Counter[int], least: int) -> str:
    """The share of videos counted at ``least`` frames or more, as a percentage."""
    total = sum(counts.values())
    return f"{100 * sum(n for k, n in counts.items() if k >= least) / max(total, 1):.0f}%"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", default="data/val_probes")
    parser.add_argument("--train_root", default="data/states_10k")
    parser.add_argument("--clips", type=int, default=3000)
    parser.add_argument("--concepts", nargs="+", default=list(specs.QUADRUPLET_CONCEPTS))
    args = parser.parse_args()
    print(
        "| concept | pairs | seen in ≥ 1 frame to the change | seen whole in ≥ 1 | in ≥ 2 "
        "| frames seen whole (videos) | training examples seen whole in ≥ 2 frames |"
    )
    print("|---|---|---|---|---|---|---|")
    for concept in args.concepts:
        seen, whole = probes(args.root, concept)
        trained = examples(args.train_root, concept, args.clips)
        spread = ", ".join(f"{k}: {n}" for k, n in sorted(whole.items()))
        print(
            f"| {concept} | {sum(seen.values())} | {share(seen, 1)} | {share(whole, 1)} | "
            f"{share(whole, 2)} | {spread} | {share(trained, 2)} of {sum(trained.values())} |"
        )


if __name__ == "__main__":
    main()
