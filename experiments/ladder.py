"""What each rung and removal of docs/study/learned_physics.md shows: from tested runs' reports,
a Markdown table with per concept each run's verdict, its quadruplet t (unchangeableness: per
change) and halves' M, and whether both halves are significant on their own; then per run the
count of verdicts and of concepts whose halves all stand alone, where the report has one the
same for its untrained copy (priors alone), and the largest correlation of its d with a cue's.

    python experiments/learned_physics.py LABEL=REPORT_DIR [LABEL=REPORT_DIR ...]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Any

from voe_lightning import specs
from voe_lightning.report.summary_file import read_summary
from voe_lightning.stats.statistics_format import format_number


def cell(summary: dict[str, Any], concept: str) -> str:
    """One concept's cell: verdict, quadruplet t(s), halves' M, '†' if a half is not
    significant on its own."""
    rows = {(r["concept"], r["variant"]): r for r in summary["rows"]}
    verdict = next((v for v in summary["verdicts"] if v["concept"] == concept), None)
    if verdict is None:
        return "n/a"
    parts = []
    for row in specs.QUADRUPLETS[concept]:
        r = rows.get((concept, row))
        if r is None or r.get("t") is None:
            parts.append("n/a")
            continue
        halves = (
            f" ({format_number(r['first_half'], '.3g')} / {format_number(r['second_half'], '.3g')})"
        )
        parts.append(
            format_number(r["t"], ".2f") + (halves if len(specs.QUADRUPLETS[concept]) == 1 else "")
        )
    mark = "" if verdict.get("halves_significant") in (True, None) else "†"
    name = "**VOE**" if verdict["voe"] else "no VOE"
    return f"{name} {', '.join(parts)}{mark}"


def counts(summary: dict[str, Any]) -> str:
    """'k of 5 (halves: j)': verdicts, and concepts whose halves all stand alone."""
    verdicts = summary["verdicts"]
    voe = sum(bool(v["voe"]) for v in verdicts)
    halves = sum(bool(v.get("halves_significant")) for v in verdicts)
    return f"**{voe} of {len(verdicts)}** (halves alone: {halves})"


def table(runs: list[tuple[str, Path]]) -> str:
    summaries = [(label, read_summary(path)) for label, path in runs]
    lines = [
        "| concept | " + " | ".join(label for label, _ in summaries) + " |",
        "|---|" + "---|" * len(summaries),
    ]
    for concept in specs.CONCEPTS:
        lines.append(
            f"| {concept.replace('_', ' ')} | "
            + " | ".join(cell(summary, concept) for _, summary in summaries)
            + " |"
        )
    lines.append("| **verdicts** | " + " | ".join(counts(s) for _, s in summaries) + " |")
    alone = [s.get("priors_alone") for _, s in summaries]
    if any(alone):
        lines.append(
            "| untrained (priors alone) | "
            + " | ".join(counts(a) if a else "" for a in alone)
            + " |"
        )
    lines.append(
        "| largest cue correlation | " + " | ".join(largest_cue(p) for _, p in runs) + " |"
    )
    return "\n".join(lines) + "\n\n† a half not significant on its own at the report's alpha.\n"


def largest_cue(report_dir: Path) -> str:
    """The largest |r| between the model's d and a physics-blind cue's d over the report's
    probe-variant rows (cue_correlations.csv; not the pooled rows, which mix variants whose cue
    d have opposite signs, nor the within-variant ones), with where it is."""
    path = report_dir / "cue_correlations.csv"
    if not path.exists():
        return "n/a"
    with open(path) as handle:
        rows = [
            row
            for row in csv.DictReader(handle)
            if row["r"] not in ("", "nan") and row["variant"] in specs.VARIANTS
        ]
    if not rows:
        return "n/a"
    top = max(rows, key=lambda row: abs(float(row["r"])))
    return f"r = {float(top['r']):+.2f} ({top['concept']}/{top['variant']}, {top['cue']})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="LABEL=REPORT_DIR (a voe_report folder)")
    args = parser.parse_args()
    runs = []
    for run in args.runs:
        label, _, path = run.partition("=")
        runs.append((label, Path(path)))
    print(table(runs), end="")


if __name__ == "__main__":
    main()
