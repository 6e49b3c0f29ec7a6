"""The followers table of docs/study/shortcuts.md: every physics-blind follower of per-object
inputs (``ObjectFollower``: each rule of ``RULES`` on ``states`` and on ``masks``) tested with
``test`` on one probe set, then the Markdown table of their verdicts (``learned_physics.table``).
A concept a follower passes can be passed without physics from that input.

    python experiments/follower_audit.py --seed_offset 7000000 [--config configs/cpu.yaml]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from learned_physics import table

from voe_lightning.model.scorers.followers import INPUTS, RULES


def run_follower(config: str, seed_offset: int, features: str, rule: str, save_dir: str) -> Path:
    """``test`` of one follower on the config's probes at ``seed_offset``; its report folder."""
    name = f"follower_{features}_{rule}"
    command = [
        sys.executable,
        "-m",
        "voe_lightning",
        "test",
        "--config",
        config,
        "--model",
        "voe_lightning.model.ObjectFollower",
        "--model.init_args.rule",
        rule,
        "--model.init_args.features",
        features,
        "--data.init_args.seed_offset",
        str(seed_offset),
        "--trainer.logger.init_args.save_dir",
        save_dir,
        "--trainer.logger.init_args.name",
        name,
    ]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{name} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return max(Path(save_dir, name).glob("version_*/voe_report"), key=lambda p: p.stat().st_mtime)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/cpu.yaml")
    parser.add_argument("--seed_offset", type=int, required=True)
    parser.add_argument("--save_dir", default="runs/followers")
    parser.add_argument("--features", nargs="+", default=list(INPUTS), choices=INPUTS)
    args = parser.parse_args()
    for features in args.features:
        runs = [
            (
                rule.replace("_", " "),
                run_follower(args.config, args.seed_offset, features, rule, args.save_dir),
            )
            for rule in RULES
        ]
        print(f"\n### Followers of {features}, seed offset {args.seed_offset}\n")
        print(table(runs), end="")


if __name__ == "__main__":
    main()
