"""Which surprise term carries an untrained object-state learner's relative surprise: per
initialization (seeds 0..N-1 of ``configs/learned_states.yaml``'s model, ``--model`` arguments
over it), the mean d per term of each quadruplet half of a concept's validation probes.

    python experiments/untrained_terms.py solidity
    python experiments/untrained_terms.py containment --model \
        '{"sight_lines": false, "floor": false, "inertia": false, "projection": false}'
"""

import argparse
import json

import numpy as np
import torch
import yaml
from violation_terms import term_surprise

from voe_lightning import specs
from voe_lightning.audit import cues
from voe_lightning.data.store import open_split
from voe_lightning.model import ObjectStateModel
from voe_lightning.model.object_state.state import SLOT_TERMS

#: Every term of the surprise (``ObjectStateModel._per_frame``).
TERMS = SLOT_TERMS + ("appear",)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("concept", choices=specs.CONCEPTS)
    parser.add_argument("--model", type=json.loads, default={}, help="model arguments (JSON)")
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument("--seeds", type=int, default=4)
    args = parser.parse_args()
    with open("configs/learned_states.yaml") as file:
        config = yaml.safe_load(file)["model"]["init_args"]
    print("| seed | half | " + " | ".join(TERMS) + " |")
    print("|---|---|" + "---|" * len(TERMS))
    for seed in range(args.seeds):
        torch.manual_seed(seed)
        model = ObjectStateModel(**(config | args.model)).eval()
        d: dict[tuple[str, str], list[float]] = {}
        for record in open_split(args.root, args.concept, "val"):
            variant = specs.VARIANTS[int(record["variant"])]
            if variant not in ("standard", "counterbalanced"):
                continue
            terms = {
                side: term_surprise(model, record[side], record["camera"]) for side in cues.SIDES
            }
            for name in terms["consistent"]:
                difference = terms["inconsistent"][name] - terms["consistent"][name]
                d.setdefault((variant, name), []).append(float(difference.sum()))
        for half in ("standard", "counterbalanced"):
            means = [np.mean(d[(half, name)]) for name in TERMS]
            print(f"| {seed} | {half} | " + " | ".join(f"{m:+.2f}" for m in means) + " |")


if __name__ == "__main__":
    main()
