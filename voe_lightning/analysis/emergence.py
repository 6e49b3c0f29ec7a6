"""When each concept's VOE emerges over training (the paper's Figure 6, read as the verdict
reads it): per concept, the validation quadruplet test's t at every validation step of each run
(``voe/<concept>/<quadruplet row>/t``, logged by ``VOEProbeCallback``), its one-tailed critical
t at the run's alpha, and a filled marker where the verdict's rule holds (p < alpha, both
halves' M > 0)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from scipy import stats

from voe_lightning import specs
from voe_lightning.analysis.training_curves import labelled_run, read_scalars
from voe_lightning.report.figures import panel_grid, save_figure
from voe_lightning.runs import base_alpha
from voe_lightning.stats.statistics import check_alpha
from voe_lightning.stats.verdicts import quadruplet_rule

#: The statistics of a quadruplet row the figure reads.
QUADRUPLET_TAG = re.compile(
    r"^voe/(?P<concept>[^/]+)/(?P<row>[^/]*quadruplet)/"
    r"(?P<statistic>t|p_value|n|first_half|second_half)$"
)

Curves = dict[str, tuple[np.ndarray, np.ndarray]]


def read_quadruplet_curves(run_dir: str | Path) -> dict[tuple[str, str], Curves]:
    """(concept, quadruplet row) -> statistic -> (steps, values) of one run."""
    curves: dict[tuple[str, str], Curves] = {}
    for tag, curve in read_scalars(run_dir, QUADRUPLET_TAG).items():
        match = QUADRUPLET_TAG.match(tag)
        assert match is not None  # read_scalars keeps the tags the pattern matches
        curves.setdefault((match["concept"], match["row"]), {})[match["statistic"]] = curve
    return curves


def first_voe_step(curves: Curves, alpha: float) -> int | None:
    """The first validation step from which the verdict's rule holds at every later step
    (the emergence of a stable VOE), None when it does not hold at the last."""
    steps, p_values = curves["p_value"]
    holds = quadruplet_rule(p_values, curves["first_half"][1], curves["second_half"][1], alpha)
    if not holds[-1]:
        return None
    failing = np.flatnonzero(~holds)
    return int(steps[failing[-1] + 1]) if failing.size else int(steps[0])


def emergence_figure(runs: Sequence[tuple[str, str | Path]], alpha: float) -> Figure:
    """One panel per concept: each run's quadruplet t over training steps (unchangeableness:
    one line per change), the critical t at ``alpha`` dashed, the steps where the verdict's rule
    holds filled, and per run the step from which it holds on (``first_voe_step``)."""
    read = [(label, read_quadruplet_curves(run_dir)) for label, run_dir in runs]
    for (_, found), (_, run_dir) in zip(read, runs):
        if not found:
            raise ValueError(
                f"{run_dir} has no voe/<concept>/quadruplet/... scalars (validation probes "
                "with seeds, VOEProbeCallback of this version, during fit)"
            )
    concepts = [c for c in specs.CONCEPTS if any(c == k[0] for _, f in read for k in f)]
    figure, axes = panel_grid(len(concepts), 4.4, 3.4, max_cols=3)
    for ax, concept in zip(axes, concepts):
        for index, (label, found) in enumerate(read):
            rows = [row for c, row in found if c == concept]
            for row_index, row in enumerate(rows):
                curves = found[(concept, row)]
                steps, t = curves["t"]
                holds = quadruplet_rule(
                    curves["p_value"][1], curves["first_half"][1], curves["second_half"][1], alpha
                )
                color = f"C{index}"
                style = ("-", "--", ":")[row_index % 3]
                first = first_voe_step(curves, alpha)
                name = label + (f" {row.removesuffix('_quadruplet')}" if len(rows) > 1 else "")
                ax.plot(
                    steps,
                    t,
                    color=color,
                    linestyle=style,
                    label=f"{name}: VOE from {first}" if first is not None else f"{name}: none",
                )
                ax.scatter(steps[holds], t[holds], color=color, s=14, zorder=3)
                ax.scatter(
                    steps[~holds], t[~holds], facecolors="none", edgecolors=color, s=14, zorder=3
                )
        n = max(int(f[k]["n"][1][-1]) for _, f in read for k in f if k[0] == concept)
        ax.axhline(stats.t.ppf(1 - alpha, n - 1), color="black", linestyle="--", linewidth=0.8)
        ax.axhline(0.0, color="grey", linewidth=0.6)
        ax.set_title(concept.replace("_", " "), fontsize=10)
        ax.set_xlabel("training step")
        ax.set_ylabel(f"quadruplet t({n - 1})")
        ax.legend(fontsize=6)
    figure.suptitle(
        f"When VOE emerges: validation quadruplet t over training (dashed: critical t at "
        f"alpha = {alpha:g}; filled: p < alpha with both halves' M > 0)",
        fontsize=9,
    )
    return figure


def emergence(runs: list[str], out: Path, alpha: float | None = None) -> Path:
    """When each concept's VOE emerges over training: the validation quadruplet t per concept
    and run, the critical t and where the verdict holds, as a PNG (paper Figure 6).

    Args:
        runs: run directories as [LABEL=]DIR (a label per seed, say).
        out: PNG to write.
        alpha: significance level (default: configs/base.yaml's).
    """
    alpha = base_alpha() if alpha is None else check_alpha(alpha)
    return save_figure(emergence_figure([labelled_run(run) for run in runs], alpha), out)
