"""Why a per-video follower of a cue's level looks like VOE (docs/calibration.md): per concept
with a counterbalanced pair and per frame-local cue, each video type's mean standardized score
u (the concept's four video types pooled, as the calibration's ``per-video square`` does), the
midpoint of each variant's pair, and the follower's d_z per variant. With mirrored differences
the follower u_inc^2 - u_con^2 has the same sign in both variants unless both midpoints sit at
the concept's mean: only cb consistent ~ standard inconsistent and cb inconsistent ~ standard
consistent, in every cue, makes it wrong in one variant.

    python experiments/cue_levels.py --root data/calibration
"""

import argparse

import numpy as np

from voe_lightning import specs
from voe_lightning.audit import cues, video_cues


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", default="data/calibration")
    parser.add_argument("--split", default="test")
    parser.add_argument("--concepts", nargs="*", default=None, help="default: every concept")
    args = parser.parse_args()
    pooled = [
        concept
        for concept in (args.concepts or specs.CONCEPTS)
        if "counterbalanced" in specs.STANDARD_VARIANTS[concept]
    ]
    audit = cues.audit_split(args.root, args.split, pooled, progress=True)
    print(
        "| concept | cue | standard: consistent → inconsistent (midpoint) | counterbalanced: "
        "consistent → inconsistent (midpoint) | per-video square d_z: standard / "
        "counterbalanced |"
    )
    print("|---" * 5 + "|")
    for concept in pooled:
        variants = specs.STANDARD_VARIANTS[concept]
        rows = (audit.concepts == concept) & np.isin(audit.variants, variants)
        for cue in video_cues.FRAME_LOCAL_CUES:
            con = audit.scores["consistent"][cue][rows]
            inc = audit.scores["inconsistent"][cue][rows]
            both = np.concatenate([con, inc])
            mean, scale = both.mean(), both.std()
            cells, effects = [], []
            for variant in variants:
                chosen = audit.variants[rows] == variant
                u_con, u_inc = (con[chosen] - mean) / scale, (inc[chosen] - mean) / scale
                midpoint = (u_con.mean() + u_inc.mean()) / 2
                cells.append(f"{u_con.mean():+.2f} → {u_inc.mean():+.2f} ({midpoint:+.2f})")
                term = u_inc**2 - u_con**2
                effects.append(f"{term.mean() / term.std():+.2f}")
            print(
                f"| {concept.replace('_', ' ')} | {cues.CUE_TITLES[cue]} | "
                + " | ".join(cells)
                + " | "
                + " / ".join(effects)
                + " |"
            )


if __name__ == "__main__":
    main()
