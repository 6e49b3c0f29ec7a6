"""The followers tables of docs/study/shortcuts.md: every physics-blind follower of per-object
inputs (``ObjectFollower``'s ``RULES`` on ``states``, ``masks`` and ``rgbd``) on one probe set, read
from the followers' rows of a report's cue audit (one ``test`` per input: a follower reads that
input, so its report audits all seven), each follower's verdicts decided by the report's rule.
A concept a follower passes can be passed without physics from that input.

    python experiments/follower_audit.py --seed_offset 8000000 [--config configs/cpu.yaml]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from ladder import cell, counts

from voe_lightning import specs
from voe_lightning.model.scorers.followers import INPUTS, RULES
from voe_lightning.stats.verdicts import concept_verdicts


def audited_report(config: str, seed_offset: int, features: str, save_dir: str) -> Path:
    """``test`` of a follower of ``features`` on the config's probes at ``seed_offset``; its
    report folder, whose cue audit holds every follower of that input."""
    name = f"followers_of_{features}"
    command = [
        *(sys.executable, "-m", "voe_lightning", "test", "--config", config),
        *("--model", "voe_lightning.model.ObjectFollower"),
        *("--model.init_args.features", features),
        *("--data.init_args.seed_offset", str(seed_offset)),
        *("--trainer.logger.init_args.save_dir", save_dir),
        *("--trainer.logger.init_args.name", name),
    ]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{name} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return max(Path(save_dir, name).glob("version_*/voe_report"), key=lambda p: p.stat().st_mtime)


def follower_summaries(report: Path, features: str) -> list[tuple[str, dict[str, Any]]]:
    """(title, summary-like document: its rows and the report's verdicts of them) per follower
    of ``features`` in ``report``'s cue audit (cues.json)."""
    rows = json.loads((report / "cues.json").read_text())["rows"]
    summaries = []
    for rule in RULES:
        own = [row for row in rows if row["cue"] == f"{features}_{rule}"]
        verdicts = concept_verdicts(own, alpha=own[0]["alpha"])
        document = {"rows": own, "verdicts": [dataclasses.asdict(v) for v in verdicts]}
        summaries.append((rule.replace("_", " "), document))
    return summaries


def table(summaries: list[tuple[str, dict[str, Any]]]) -> str:
    """The Markdown table of the followers' verdicts per concept, and their counts."""
    lines = [
        "| concept | " + " | ".join(title for title, _ in summaries) + " |",
        "|---|" + "---|" * len(summaries),
    ]
    for concept in specs.CONCEPTS:
        cells = " | ".join(cell(summary, concept) for _, summary in summaries)
        lines.append(f"| {concept.replace('_', ' ')} | {cells} |")
    lines.append("| **verdicts** | " + " | ".join(counts(s) for _, s in summaries) + " |")
    return "\n".join(lines) + "\n\n† a half not significant on its own at the report's alpha.\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/cpu.yaml")
    parser.add_argument("--seed_offset", type=int, required=True)
    parser.add_argument("--save_dir", default="runs/followers")
    parser.add_argument("--features", nargs="+", default=list(INPUTS), choices=INPUTS)
    args = parser.parse_args()
    for features in args.features:
        report = audited_report(args.config, args.seed_offset, features, args.save_dir)
        print(f"\n### Followers of {features}, seed offset {args.seed_offset}\n", flush=True)
        print(table(follower_summaries(report, features)), end="", flush=True)


if __name__ == "__main__":
    main()
