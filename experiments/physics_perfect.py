"""What r with the frame-local cues does perfect physics give on the test probes (round
nineteen)? The physics-perfect observer (``cues.physics_perfect_surprise``) against trained
runs: per concept, the observer's largest |r| in each variant and within variants (and given
the seen extent), and the runs' largest |r| within variants and given the seen extent, with how
many runs stay at or under the bound. Each run's d is read from its ``pairs.csv``.

    python experiments/physics_perfect.py --root data/cpu --runs runs/r18_s*/version_0
    python experiments/physics_perfect.py --root data/cpu --state_scale 0.2
"""

import argparse
from pathlib import Path

import numpy as np

from voe_lightning import specs
from voe_lightning.audit import cues
from voe_lightning.report.pairs import PairResults
from voe_lightning.runs import base_alpha

#: The issue's bound on a model's |r| with every frame-local cue.
BOUND = 0.3


def largest(tracked, concept: str, variant: str) -> tuple[float, str]:
    """|r| and cue title of the frame-local cue with the largest |r| in one row group
    (``tracked``: ``cues.tracked_cues`` of the rows)."""
    row = tracked[(concept, variant)]
    return abs(row["r"]), cues.CUE_TITLES[row["cue"]]


def run_difference(run: Path, audit: cues.CueAudit, seeds: np.ndarray) -> np.ndarray:
    """The run's relative surprise per pair of ``audit`` (matched by concept, variant, seed),
    from its pairs.csv (``PairResults``, which checks the file)."""
    results = PairResults.from_csv(run / "voe_report" / "pairs.csv")
    d = dict(
        zip(zip(results.concept, results.variant, results.seed.tolist()), results.relative_surprise)
    )
    return np.array([d[key] for key in zip(audit.concepts, audit.variants, seeds.tolist())])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--root", default="data/cpu")
    parser.add_argument("--runs", nargs="*", type=Path, default=[])
    parser.add_argument(
        "--concepts",
        nargs="+",
        choices=specs.CONCEPTS,
        default=[
            concept
            for concept in specs.CONCEPTS
            if "counterbalanced" in specs.STANDARD_VARIANTS[concept]
        ],
    )
    parser.add_argument(
        "--state_scale",
        type=float,
        default=cues.STATE_SCALE,
        help="metres (and radians) of state difference worth one object-frame",
    )
    args = parser.parse_args()
    cues.STATE_SCALE = args.state_scale  # read by physics_perfect_surprise at each call
    from voe_lightning.data.store import open_split

    audits, seeds = [], []
    for concept in args.concepts:
        records = open_split(args.root, concept, "test")
        audits.append(cues.audit_records(records[k] for k in range(len(records))))
        seeds += [int(records[k]["seed"]) for k in range(len(records))]
    audit, seeds = cues.CueAudit.concatenate(audits), np.array(seeds)
    observer = cues.tracked_cues(
        audit.model_correlations(audit.physics_perfect, alpha=base_alpha())
    )
    runs = {
        run: cues.tracked_cues(
            audit.model_correlations(run_difference(run, audit, seeds), alpha=base_alpha())
        )
        for run in args.runs
    }
    print(
        f"| concept | physics-perfect observer: standard / counterbalanced | within variants "
        f"| given the seen extent | runs within variants: largest \\|r\\| | ≤ {BOUND} "
        f"| given the seen extent | ≤ {BOUND} |"
    )
    print("|---" * 8 + "|")
    for concept in args.concepts:
        per_variant = " / ".join(
            "{:.2f} ({})".format(*largest(observer, concept, variant))
            for variant in specs.STANDARD_VARIANTS[concept]
        )
        cells = [per_variant] + [
            "{:.2f} ({})".format(*largest(observer, concept, name))
            for name in (cues.WITHIN_VARIANTS, cues.GIVEN_EXTENT)
        ]
        for name in (cues.WITHIN_VARIANTS, cues.GIVEN_EXTENT):
            values = [largest(rows, concept, name)[0] for rows in runs.values()]
            cells += (
                [
                    f"{min(values):.2f} to {max(values):.2f}",
                    f"{sum(value <= BOUND for value in values)} of {len(values)}",
                ]
                if values
                else ["", ""]
            )
        print(f"| {concept.replace('_', ' ')} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
