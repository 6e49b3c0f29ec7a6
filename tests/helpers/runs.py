"""Run folders the tests read: TensorBoard curves written like a training run's, a copy of a
trained run to write into, and the command that resumes it."""

import shutil
from pathlib import Path

import numpy as np
from torch.utils.tensorboard import SummaryWriter

from helpers.locations import TINY_CONFIG

#: ``fit`` resuming the tiny config's run named ``trained`` (``copy_of``) for one more step.
RESUME_TRAINED = [
    "fit",
    "--config",
    str(TINY_CONFIG),
    "--trainer.logger.init_args.name",
    "trained",
    "--ckpt_path",
    "last",
    "--trainer.max_steps",
    "2",
]


def write_events(run_dir, curves, steps=range(0, 500, 100), other_tags=True):
    """TensorBoard scalars voe/<concept>/<variant>/relative_surprise = curve(step)."""
    writer = SummaryWriter(str(run_dir))
    for step in steps:
        for (concept, variant), curve in curves.items():
            writer.add_scalar(f"voe/{concept}/{variant}/relative_surprise", curve(step), step)
            if other_tags:
                writer.add_scalar(f"voe/{concept}/{variant}/t", 2 * curve(step), step)
        if other_tags:
            writer.add_scalar("train/loss", 1.0 / (step + 1), step)
    writer.close()


def curve_runs(root: Path) -> list[tuple[str, Path]]:
    """Event files under ``root`` of a joint run and a separate run per concept whose relative
    surprise rises like a * log(1 + step / 50), the separate runs' at 0.6 of the joint's; as
    (label, folder) pairs."""
    concepts = {
        ("object_persistence", "standard"): 0.5,
        ("object_persistence", "counterbalanced"): 0.3,
        ("unchangeableness", "color"): 0.8,
    }
    write_events(
        root / "joint", {k: (lambda s, a=a: a * np.log1p(s / 50)) for k, a in concepts.items()}
    )
    for (concept, variant), a in concepts.items():
        write_events(
            root / f"separate_{concept}",
            {(concept, variant): (lambda s, a=a: 0.6 * a * np.log1p(s / 50))},
        )
    return [("joint", root / "joint")] + [
        ("separate", root / f"separate_{c}") for c in ("object_persistence", "unchangeableness")
    ]


def copy_of(run: Path, workdir: Path) -> Path:
    """``run`` copied to ``workdir``/runs/trained/version_0 (tests write into it)."""
    target = workdir / "runs" / "trained" / "version_0"
    shutil.copytree(run, target)
    return target
