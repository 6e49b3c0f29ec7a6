"""Does a model's surprise follow a frame-local cue, or the size of the violation that the cue
also follows? For object persistence's test pairs: per pair, the model's d (the run's
pairs.csv), the cue's difference (inconsistent less consistent, summed after the manipulation
frame, as the cue audit scores it) and the violation's size (how far apart the plank comes to
rest in the two videos, in metres); Pearson r of each two and the partial r of d and the cue
given the size, within each variant.

    python docs/study/scripts/cue_through_violation.py runs/r11_s0/version_0 --root data/cpu
"""

import argparse
import csv
from pathlib import Path

import numpy as np
import torch
from scipy import stats

from voe_lightning import cues, specs
from voe_lightning.store import open_split

CONCEPT = "object_persistence"


def partial_r(x: np.ndarray, y: np.ndarray, given: np.ndarray) -> float:
    """Pearson r of ``x`` and ``y`` after regressing each on ``given`` (with an intercept)."""
    design = np.column_stack([np.ones_like(given), given])
    residual = [v - design @ np.linalg.lstsq(design, v, rcond=None)[0] for v in (x, y)]
    return float(stats.pearsonr(*residual)[0])


def pair_table(root: str, cue: str) -> dict[tuple[int, str], tuple[float, float]]:
    """Per test pair of CONCEPT, by (seed, variant): its cue difference and violation size."""
    table = {}
    for record in open_split(root, CONCEPT, "test"):
        m = record["manipulation_frame"].reshape(1)
        score, rest = {}, {}
        for side in cues.SIDES:
            video = record[side]
            score[side] = float(cues.score_videos(video["frames"][None], video["mask"][None],
                                                  m)[cue][0])
            objects = video["objects"]
            plank = int(objects["size"][0].amax(-1).argmax())
            rest[side] = float(objects["position"][-1, plank, 2])
        key = (int(record["seed"]), specs.VARIANTS[int(record["variant"])])
        table[key] = (score["inconsistent"] - score["consistent"],
                      abs(rest["inconsistent"] - rest["consistent"]))
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="run folders with voe_report/pairs.csv")
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument("--cue", default="motion_energy", choices=cues.CUES)
    args = parser.parse_args()
    torch.set_num_threads(1)
    table = pair_table(args.root, args.cue)
    print(f"| run | variant | n | r(d, {args.cue}) | r({args.cue}, size) | r(d, size) | "
          f"partial r(d, {args.cue} given size) |")
    print("|---|---|---|---|---|---|---|")
    for run in args.runs:
        with open(Path(run) / "voe_report" / "pairs.csv", newline="") as file:
            pairs = [row for row in csv.DictReader(file) if row["concept"] == CONCEPT]
        for variant in specs.STANDARD_VARIANTS[CONCEPT]:
            rows = [(float(row["relative_surprise"]), *table[(int(row["seed"]), variant)])
                    for row in pairs if row["variant"] == variant]
            d, cue, size = np.array(rows).T
            print(f"| {run} | {variant} | {len(rows)} | {stats.pearsonr(d, cue)[0]:+.2f} | "
                  f"{stats.pearsonr(cue, size)[0]:+.2f} | {stats.pearsonr(d, size)[0]:+.2f} | "
                  f"{partial_r(d, cue, size):+.2f} |")


if __name__ == "__main__":
    main()
