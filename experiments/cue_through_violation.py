"""Does a model's surprise follow a frame-local cue, or what the objects did that the cue also
follows? Per test pair: the model's d (the run's pairs.csv), each cue's difference
(inconsistent less consistent, summed after the manipulation frame, as the cue audit scores it)
and a physical difference read from the records' object states; Pearson r of d and the cue,
and the partial r of the two given the physical difference, within each variant.

``--given motion`` (any concept): how much farther the objects moved (m) and turned (rad) after
the manipulation frame, and in how many more object-frames they were seen, inconsistent less
consistent. ``--given reveal`` (containment, round fifteen): after the manipulation frame, at
which frame the cube (the smallest object) is first seen and in how many frames it is seen, in
each video (not a difference: the standard consistent cube is mostly never seen), and the
manipulation frame itself. ``--given rest`` (object persistence, round eleven): how far apart
the plank comes to rest in the two videos (m). ``--given settling`` (object persistence, round
seventeen): in each video, how far the plank still moves (m) and turns (rad) once it has landed.
``--given extent`` (any concept, round eighteen): how much of the violation is seen, in
object-frames, not pixels (``cues.seen_extent``; the report's "given the seen extent" row).

    python experiments/cue_through_violation.py runs/r12_s0/version_0 --given motion
    python experiments/cue_through_violation.py runs/r15_s0/version_0 --given reveal \
        --concepts containment
    python experiments/cue_through_violation.py runs/r11_s0/version_0 --root data/cpu
    python experiments/cue_through_violation.py runs/r16_s0/version_0 --given settling \
        --concepts object_persistence
    python experiments/cue_through_violation.py runs/r18_s0/version_0 --given extent \
        --concepts containment
"""

import argparse
from pathlib import Path

import numpy as np
import torch
from scipy import stats

from voe_lightning import specs
from voe_lightning.audit import cues, video_cues
from voe_lightning.data.store import open_split
from voe_lightning.report.pairs import PairResults

#: The physical differences of ``--given motion`` and ``--given reveal``, in column order.
PHYSICAL = {
    "motion": ("path", "turn", "seen"),
    "reveal": ("first inc", "first con", "seen inc", "seen con", "m"),
    "settling": ("path con", "turn con", "path inc", "turn inc"),
    "extent": cues.EXTENT_COLUMNS,
}
#: A falling plank has landed once a frame takes it down by less than this (m; it falls 0.3 to
#: 0.8 m a frame before).
LANDED = 0.2


def partial_r(x: np.ndarray, y: np.ndarray, given: list[np.ndarray]) -> float:
    """Pearson r of ``x`` and ``y`` after regressing each on ``given`` (with an intercept; a
    constant one is left out)."""
    design = np.column_stack([np.ones_like(x)] + [g for g in given if np.ptp(g) > 0])
    residual = [v - design @ np.linalg.lstsq(design, v, rcond=None)[0] for v in (x, y)]
    return float(stats.pearsonr(*residual)[0])


def plank_rest(objects, m: int) -> dict[str, float]:
    """Where the plank (the object with the longest side) is at the last frame: its height."""
    plank = int(objects["size"][0].amax(-1).argmax())
    return {"rest": float(objects["position"][-1, plank, 2])}


def object_motion(objects, m: int) -> dict[str, float]:
    """What the objects did after frame m, summed over them: the distance their centres moved
    (m), the angle they turned through (rad; each step's rotation between consecutive
    orientations) and the object-frames in which some of them is seen."""
    present = (objects["shape_label"] > 0).numpy()
    both = present[1:] & present[:-1]  # an object parked out of view does not move
    position = objects["position"].double().numpy()
    orientation = objects["orientation"].double().numpy()
    moved = np.linalg.norm(np.diff(position, axis=0), axis=-1) * both
    cosine = np.abs((orientation[1:] * orientation[:-1]).sum(-1)).clip(0.0, 1.0)
    turned = 2.0 * np.arccos(cosine) * both
    seen = (objects["visible_fraction"] > 0).numpy()
    return {
        "path": float(moved[m:].sum()),
        "turn": float(turned[m:].sum()),
        "seen": float(seen[m + 1 :].sum()),
    }


def landing_frame(height, m: int) -> int | None:
    """The first frame after m that a frame's move took down by less than ``LANDED`` (a falling
    plank has landed there), from the heights [T] of one object; None if it never lands."""
    drop = np.asarray(height[:-1]) - np.asarray(height[1:])
    landed = np.flatnonzero(drop[m:] < LANDED)
    return m + 1 + int(landed[0]) if len(landed) else None


def plank_settling(objects, m: int) -> dict[str, float]:
    """How much the plank (the object with the longest side) still moves once it has landed
    (the first frame after m that takes it down by less than ``LANDED``): the distance its
    centre moves (m) and the angle it turns through (rad) from then to the end."""
    plank = int(objects["size"][0].amax(-1).argmax())
    position = objects["position"][:, plank].double().numpy()
    orientation = objects["orientation"][:, plank].double().numpy()
    landed = landing_frame(position[:, 2], m)
    landed = len(position) - 1 if landed is None else landed
    moved = np.linalg.norm(np.diff(position[landed:], axis=0), axis=-1)
    cosine = np.abs((orientation[landed + 1 :] * orientation[landed:-1]).sum(-1)).clip(0.0, 1.0)
    return {"path": float(moved.sum()), "turn": float((2.0 * np.arccos(cosine)).sum())}


def cube_reveal(objects, m: int) -> dict[str, float]:
    """When the cube (the object of smallest box) shows after frame m: the first frame after m
    in which it is seen (counted from m + 1; the frames left if never) and how many it is
    seen in."""
    present = objects["shape_label"][0] > 0
    cube = int(objects["size"][0].prod(-1).masked_fill(~present, torch.inf).argmin())
    seen = (objects["visible_fraction"][m + 1 :, cube] > 0).numpy()
    shown = np.flatnonzero(seen)
    return {"first": float(shown[0] if len(shown) else len(seen)), "seen": float(seen.sum())}


def pair_table(root: str, concept: str, given: str) -> dict[tuple[int, str], dict[str, float]]:
    """Per test pair of ``concept``'s standard variants, by (seed, variant): each frame-local
    cue's difference and the physical quantities (``PHYSICAL[given]``, or ``rest``: how far
    apart the plank rests)."""
    physical = {
        "motion": object_motion,
        "reveal": cube_reveal,
        "rest": plank_rest,
        "settling": plank_settling,
    }.get(given)  # extent: of the pair, not a video
    table = {}
    for record in open_split(root, concept, "test"):
        variant = specs.VARIANTS[int(record["variant"])]
        if variant not in specs.STANDARD_VARIANTS[concept]:
            continue
        m = record["manipulation_frame"].reshape(1)
        score, state = {}, {}
        for side in cues.SIDES:
            video = record[side]
            score[side] = video_cues.score_videos(video["frames"][None], video["mask"][None], m)
            state[side] = physical(video["objects"], int(m)) if physical else {}
        row = {
            cue: float(score["inconsistent"][cue][0] - score["consistent"][cue][0])
            for cue in video_cues.FRAME_LOCAL_CUES
        }
        if given == "motion":
            row.update(
                {
                    key: state["inconsistent"][key] - state["consistent"][key]
                    for key in PHYSICAL[given]
                }
            )
        elif given == "reveal":
            row.update(
                {
                    f"{key} {side[:3]}": state[side][key]
                    for side in cues.SIDES
                    for key in ("first", "seen")
                },
                m=float(m),
            )
        elif given == "extent":
            extent = cues.seen_extent(
                record["inconsistent"]["objects"]["visible_fraction"][None],
                record["consistent"]["objects"]["visible_fraction"][None],
                m,
            )
            row.update(zip(PHYSICAL[given], extent[0].tolist()))
        elif given == "settling":
            row.update(
                {
                    f"{key} {side[:3]}": state[side][key]
                    for side in cues.SIDES
                    for key in ("path", "turn")
                }
            )
        else:
            row["size"] = abs(state["inconsistent"]["rest"] - state["consistent"]["rest"])
        table[(int(record["seed"]), variant)] = row
    return table


def run_pairs(run: str, concept: str, variant: str) -> tuple[np.ndarray, np.ndarray]:
    """The seeds of a run's test pairs of ``concept``'s ``variant`` and each pair's d, from its
    pairs.csv (``PairResults``, which checks the file)."""
    results = PairResults.from_csv(Path(run) / "voe_report" / "pairs.csv")
    chosen = (np.asarray(results.concept) == concept) & (np.asarray(results.variant) == variant)
    return results.seed[chosen], results.relative_surprise[chosen]


def print_rest(runs: list[str], table: dict, cue: str) -> None:
    """Round eleven's table: object persistence, one cue, given the rest distance."""
    print(
        f"| run | variant | n | r(d, {cue}) | r({cue}, size) | r(d, size) | "
        f"partial r(d, {cue} given size) |"
    )
    print("|---|---|---|---|---|---|---|")
    for run in runs:
        for variant in specs.STANDARD_VARIANTS["object_persistence"]:
            seeds, d = run_pairs(run, "object_persistence", variant)
            score, size = np.array(
                [[table[(int(seed), variant)][key] for key in (cue, "size")] for seed in seeds]
            ).T
            print(
                f"| {run} | {variant} | {len(d)} | {stats.pearsonr(d, score)[0]:+.2f} | "
                f"{stats.pearsonr(score, size)[0]:+.2f} | {stats.pearsonr(d, size)[0]:+.2f} | "
                f"{partial_r(d, score, [size]):+.2f} |"
            )


def print_given(runs: list[str], tables: dict[str, dict], keys: tuple[str, ...]) -> None:
    """Per run, concept and variant: r(d, cue) -> partial r given the physical differences
    ``keys`` for every frame-local cue, and r of d with each of them."""
    titles = " | ".join(cues.CUE_TITLES[cue] for cue in video_cues.FRAME_LOCAL_CUES)
    print(f"r(d, cue) -> partial r given {', '.join(keys)}\n")
    print(f"| run | concept | variant | n | {titles} | r(d, {' / '.join(keys)}) |")
    print("|---" * (5 + len(video_cues.FRAME_LOCAL_CUES)) + "|")
    for run in runs:
        for concept, table in tables.items():
            for variant in specs.STANDARD_VARIANTS[concept]:
                seeds, d = run_pairs(run, concept, variant)
                rows = [table[(int(seed), variant)] for seed in seeds]
                column = {key: np.array([row[key] for row in rows]) for key in rows[0]}
                given = [column[key] for key in keys]
                cells = [
                    f"{stats.pearsonr(d, column[cue])[0]:+.2f} -> "
                    f"{partial_r(d, column[cue], given):+.2f}"
                    for cue in video_cues.FRAME_LOCAL_CUES
                ]
                physical = " / ".join(
                    f"{stats.pearsonr(d, column[key])[0]:+.2f}"
                    if np.ptp(column[key]) > 0
                    else "const"
                    for key in keys
                )
                print(
                    f"| {Path(run).parent.name} | {concept} | {variant} | {len(d)} | "
                    f"{' | '.join(cells)} | {physical} |"
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="run folders with voe_report/pairs.csv")
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument("--given", default="rest", choices=("rest", *PHYSICAL))
    parser.add_argument(
        "--cue",
        default="motion_energy",
        choices=video_cues.FRAME_LOCAL_CUES,
        help="the cue of --given rest",
    )
    parser.add_argument(
        "--concepts",
        nargs="+",
        choices=specs.CONCEPTS,
        default=["object_persistence", "continuity", "solidity", "containment"],
        help="the concepts of --given motion, reveal, settling or extent",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.given == "rest":
        print_rest(args.runs, pair_table(args.root, "object_persistence", "rest"), args.cue)
    else:
        print_given(
            args.runs,
            {concept: pair_table(args.root, concept, args.given) for concept in args.concepts},
            PHYSICAL[args.given],
        )


if __name__ == "__main__":
    main()
