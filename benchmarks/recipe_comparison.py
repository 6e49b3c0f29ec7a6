"""Training recipes compared at equal sequences seen (docs/performance.md, "Large batches"): for
each fitted run, the training loss over the last quarter of its sequences, the validation
probes' mean consistent surprise (``val/kl``), and each concept and variant's t at the last
validation with the concept's verdict count, as a Markdown table.

    python benchmarks/recipe_comparison.py --runs "batch 8=runs/recipe_b8/version_0" \\
        "batch 64=runs/recipe_b64/version_0"
"""

from __future__ import annotations

import argparse

import numpy as np

from voe_lightning.analysis.training_curves import read_scalars

VARIANT_T = r"voe/([a-z_]+)/([a-z_]+)/t$"


def summarize(run: str) -> dict:
    """The comparison's numbers of one run directory."""
    scalars = read_scalars(run, r"(train/loss|val/kl|voe/.*/t)$")
    steps, loss = scalars["train/loss"]
    last_quarter = steps >= steps.max() * 0.75
    row = {
        "loss": float(np.mean(loss[last_quarter])),
        "val/kl": float(scalars["val/kl"][1][-1]),
        "validated at": int(scalars["val/kl"][0][-1]),
    }
    for tag, (_, values) in scalars.items():
        if tag.startswith("voe/"):
            row[tag.removeprefix("voe/").removesuffix("/t")] = float(values[-1])
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", nargs="+", required=True, help="LABEL=RUN_DIR per recipe")
    args = parser.parse_args()
    labelled = [run.split("=", 1) for run in args.runs]
    rows = {label: summarize(path) for label, path in labelled}
    keys = list(next(iter(rows.values())))
    print("| | " + " | ".join(rows) + " |\n|---|" + "---|" * len(rows))
    for key in keys:
        cells = [rows[label].get(key) for label in rows]
        shown = [f"{value:,.2f}" if isinstance(value, float) else str(value) for value in cells]
        print(
            f"| {key if key in ('loss', 'val/kl', 'validated at') else 't ' + key} | "
            + " | ".join(shown)
            + " |"
        )


if __name__ == "__main__":
    main()
