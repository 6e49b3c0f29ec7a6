"""Which of an object-state learner's surprise terms (visibility, state, shape, newcomers'
terms, a newcomer's appearance) each quadruplet half rests on: per concept and half of a probe
split, the mean over pairs of d = S(inconsistent) - S(consistent) by term (each term's rectified
excess summed over frames and slots, as ``ObjectStateModel.surprise`` sums them) and its
one-sample t, and per quadruplet row the t of D = the two halves' total d summed per seed. A half
that fails on one term and passes on another names what the learner lacks.

    python experiments/surprise_terms.py runs/rgbd_15min/version_0/checkpoints/last.ckpt \
        --root data/states_10k --split val
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np
import torch
from scipy import stats

from voe_lightning import specs
from voe_lightning.data.store import open_split
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.likelihood import rectified_excess
from voe_lightning.model.object_state.state import SLOT_TERMS

TERMS = (*SLOT_TERMS, "appear")


def rollout_of(model: ObjectStateModel, video, camera) -> dict[str, torch.Tensor]:
    """The learner's rollout of one video (a batch of one), from the inputs it reads."""
    read = model.inputs_read()
    inputs = {name: video[name][None] for name in ("objects", "mask", "depth") if name in read}
    with torch.no_grad():
        return model.rollout(model._inputs(video["frames"][None], camera=camera[None], **inputs))


def term_totals(model: ObjectStateModel, video, camera) -> dict[str, float]:
    """One video's surprise by term, summed over frames and slots."""
    out = rollout_of(model, video, camera)
    return {
        name: float(rectified_excess(out[name], out[f"{name}_entropy"]).sum()) for name in TERMS
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--root", default="data/states_10k")
    parser.add_argument("--split", default="val")
    parser.add_argument("--concepts", nargs="+", default=list(specs.QUADRUPLET_CONCEPTS))
    args = parser.parse_args()
    model = ObjectStateModel.load_from_checkpoint(args.checkpoint, map_location="cpu").eval()
    print("| concept | half | pairs | " + " | ".join(TERMS) + " | total |")
    print("|---|---|---|" + "---|" * (len(TERMS) + 1))
    for concept in args.concepts:
        by_half: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
        by_seed: dict[str, dict[int, float]] = defaultdict(dict)
        for record in open_split(args.root, concept, args.split):
            variant = specs.VARIANTS[int(record["variant"])]
            if variant not in specs.VERDICT_VARIANTS[concept]:
                continue
            physical = term_totals(model, record["consistent"], record["camera"])
            magic = term_totals(model, record["inconsistent"], record["camera"])
            for name in TERMS:
                by_half[variant][name].append(magic[name] - physical[name])
            total = sum(magic.values()) - sum(physical.values())
            by_half[variant]["total"].append(total)
            row, _ = specs.quadruplet_half(concept, variant)
            seed = int(record["seed"])
            by_seed[row][seed] = by_seed[row].get(seed, 0.0) + total
        for variant, terms in by_half.items():
            cells = []
            for name in (*TERMS, "total"):
                d = np.asarray(terms[name])
                t = stats.ttest_1samp(d, 0.0).statistic if d.std() > 0 else float("nan")
                cells.append("0" if not d.any() else f"{d.mean():+.2f} (t {t:.1f})")
            print(f"| {concept} | {variant} | {len(terms['total'])} | " + " | ".join(cells) + " |")
        for row, seeds in by_seed.items():
            d = np.asarray(list(seeds.values()))
            print(
                f"|  {concept} | {row}: D | {len(d)} | t {stats.ttest_1samp(d, 0.0).statistic:.2f} |"
            )


if __name__ == "__main__":
    main()
