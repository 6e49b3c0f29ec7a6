"""The training-set-size sweep (paper Figure 3): train one model per training-set size, test
each on disjoint evaluation sets of test pairs, and plot how reliably relative surprise is
significant as the training set grows. ``python -m voe_lightning analyze sweep`` trains and
tests through the CLI's ``main``, handed in as ``_cli_main`` so that this module does not
import the CLI; ``analyze sweep-plot`` redraws the figure from sweep.json or tested runs."""

from __future__ import annotations

import json
import textwrap
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from voe_lightning.callbacks.outcomes import report_folders
from voe_lightning.report.figures import panel_grid, save_figure
from voe_lightning.report.pairs import PairResults
from voe_lightning.report.summary_file import read_summary
from voe_lightning.runs import trained_reports
from voe_lightning.stats.statistics import paired_test

__all__ = ["run_size_sweep", "size_sweep_figure", "sweep", "sweep_plot", "sweep_rows"]


def sweep_rows(
    results: PairResults, train_size: int, eval_sets: int, alpha: float
) -> list[dict[str, Any]]:
    """Split each concept/variant's test pairs (ordered by seed) into ``eval_sets`` disjoint
    evaluation sets and test each: one row per (concept, variant, evaluation set)."""
    if eval_sets < 1:
        raise ValueError(f"eval_sets must be at least 1, got {eval_sets}")
    rows = []
    for concept, variant, pairs in results.groups():
        if len(pairs) < 2 * eval_sets:
            raise ValueError(
                f"{concept}/{variant} has {len(pairs)} test pairs, too few for "
                f"{eval_sets} evaluation sets of at least 2 pairs"
            )
        order = np.argsort(pairs.seed, kind="stable")
        for index, chunk in enumerate(np.array_split(order, eval_sets)):
            subset = pairs.select(chunk)
            test = paired_test(
                subset.total_inconsistent, subset.total_consistent, alpha=alpha, bootstrap=0
            )
            rows.append(
                {
                    "train_size": int(train_size),
                    "eval_set": index,
                    "concept": concept,
                    "variant": variant,
                    "n": test.n,
                    "relative_surprise": test.relative_surprise,
                    "t": test.t,
                    "p_value": test.p_value,
                    "significant": test.significant,
                    "alpha": alpha,
                }
            )
    return rows


def size_sweep_figure(rows: Sequence[Mapping[str, Any]]) -> Figure:
    """Reliability of relative surprise vs training-set size (paper Figure 3): a point per
    evaluation set, green when significant; one panel per concept/variant."""
    if not rows:
        raise ValueError("no sweep rows to plot")
    keys = list(dict.fromkeys((row["concept"], row["variant"]) for row in rows))
    figure, axes = panel_grid(len(keys), 4.6, 3.6, max_cols=3)
    alphas = {row.get("alpha") for row in rows}  # rows of older sweeps do not say
    significant_label = (
        "significant"
        if len(alphas) > 1 or None in alphas
        else f"significant (p < {alphas.pop():g})"
    )
    sizes = sorted({row["train_size"] for row in rows})
    logarithmic = len(sizes) > 1 and sizes[0] > 0 and sizes[-1] / sizes[0] >= 10
    for ax, (concept, variant) in zip(axes, keys):
        mine = [row for row in rows if (row["concept"], row["variant"]) == (concept, variant)]
        for significant, color, label in (
            (True, "tab:green", significant_label),
            (False, "tab:gray", "not significant"),
        ):
            chosen = [row for row in mine if bool(row["significant"]) == significant]
            if chosen:
                ax.scatter(
                    [row["train_size"] for row in chosen],
                    [row["relative_surprise"] for row in chosen],
                    color=color,
                    edgecolor="black",
                    linewidth=0.4,
                    s=30,
                    label=label,
                    zorder=3,
                )
        ax.axhline(0.0, color="black", linewidth=0.8)
        if logarithmic:
            ax.set_xscale("log")
        ax.set_xticks(sizes, [str(size) for size in sizes])
        ax.set_xticks([], minor=True)  # a log axis labels its minor ticks over the sizes
        ax.margins(x=0.15)
        ax.set_title(f"{concept} / {variant}", fontsize=10)
        ax.set_xlabel("training set size (examples per concept)")
        ax.set_ylabel("relative surprise")
        ax.legend(fontsize=7)
    title = "Reliability of relative surprise: each point is an independent evaluation set"
    figure.suptitle(textwrap.fill(title, width=int(14 * figure.get_figwidth())), fontsize=10)
    return figure


def _report_dir(cli: Any) -> Path:
    reports = report_folders(cli.trainer.callbacks)
    if reports:
        return reports[-1]
    raise RuntimeError(
        "the test run wrote no VOE report: add voe_lightning.callbacks."
        "VOEReportCallback to the config's trainer.callbacks"
    )


def _report_alpha(report_dir: Path) -> float:
    """The significance level a voe_report was written at (its summary.json's ``alpha``). A
    missing or corrupt summary.json, or one without an alpha, is named."""
    alpha = read_summary(report_dir).get("alpha")
    if alpha is None:
        raise ValueError(f"{Path(report_dir) / 'summary.json'} gives no alpha")
    return float(alpha)


def _checkpoint(cli: Any) -> str:
    callback = cli.trainer.checkpoint_callback
    path: str = callback and (callback.last_model_path or callback.best_model_path)
    if not path:
        raise RuntimeError("the fit run saved no checkpoint (is checkpointing enabled?)")
    return path


def run_size_sweep(
    configs: Sequence[str | Path],
    sizes: Sequence[int],
    eval_sets: int = 5,
    pairs_per_set: int = 100,
    out: str | Path = "runs/size_sweep/sweep.json",
    extra_args: Sequence[str] = (),
    test_args: Sequence[str] = (),
    *,
    cli_main: Callable[[list[str]], Any],
) -> list[dict[str, Any]]:
    """Train one model per training-set size with ``cli_main(["fit", ...])``, the entry point of
    ``python -m voe_lightning`` (with each of ``configs`` in order, e.g.
    ``configs/vrnn_quickstart.yaml``; base.yaml is read first), and test it
    on ``eval_sets`` x ``pairs_per_set`` test pairs, split into disjoint evaluation sets
    (``sweep_rows``). ``extra_args`` go to both commands, ``test_args`` to ``test`` only; in
    both ``{size}`` is replaced by the size (e.g. ``--data.root=data/sweep_{size}`` to keep
    each size's dataset apart). Needs ``VOEReportCallback`` in the config's callbacks. Writes
    the rows to ``out`` after each size and returns them; plot them with
    ``size_sweep_figure(rows)``."""
    if not sizes or any(size < 1 for size in sizes):
        raise ValueError(f"sizes must be positive training-set sizes, got {list(sizes)}")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for size in sizes:
        # test_pairs goes to fit too: fit generates the store, test must find the same one.
        common = [
            *(word for config in configs for word in ("--config", str(config))),
            "--data.train_examples",
            str(size),
            "--data.test_pairs",
            str(eval_sets * pairs_per_set),
            *(arg.format(size=size) for arg in extra_args),
        ]
        fit = cli_main(["fit", *common])
        test = cli_main(
            [
                "test",
                *common,
                "--ckpt_path",
                _checkpoint(fit),
                *(arg.format(size=size) for arg in test_args),
            ]
        )
        report = _report_dir(test)
        results = PairResults.from_csv(report / "pairs.csv")
        rows.extend(sweep_rows(results, size, eval_sets, alpha=_report_alpha(report)))
        out.write_text(json.dumps(rows, indent=2) + "\n")
    return rows


def sweep(
    lightning_configs: list[Path],
    sizes: list[int],
    eval_sets: int = 5,
    pairs_per_set: int = 100,
    out: Path = Path("runs/size_sweep/sweep.json"),
    extra_args: Sequence[str] = (),
    test_args: Sequence[str] = (),
    plot: Path | None = None,
    _cli_main: Callable[[list[str]], Any] | None = None,
) -> list[dict[str, Any]]:
    """Train and test one model per training-set size, writing the rows to sweep.json.

    Args:
        lightning_configs: the fit and test configs, in order, after base.yaml (e.g. a
            study's), with VOEReportCallback in the callbacks.
        sizes: training-set sizes (examples per concept).
        eval_sets: disjoint evaluation sets per size.
        pairs_per_set: test pairs per evaluation set.
        out: JSON to write the rows to.
        extra_args: extra fit and test arguments; {size} is replaced by the size.
        test_args: extra test arguments; {size} is replaced by the size.
        plot: also write the Figure 3 PNG here.
        _cli_main: the entry point that runs fit and test; the CLI passes its own ``main``, so
            this module does not import the CLI (jsonargparse offers no optional ``_`` argument).
    """
    if _cli_main is None:
        raise TypeError(
            "sweep runs fit and test through _cli_main: run it as `python -m "
            "voe_lightning analyze sweep`, or pass voe_lightning.cli.main"
        )
    rows = run_size_sweep(
        lightning_configs,
        sizes,
        eval_sets,
        pairs_per_set,
        out,
        extra_args,
        test_args,
        cli_main=_cli_main,
    )
    if plot:
        save_figure(size_sweep_figure(rows), plot)
    return rows


def sweep_plot(
    out: Path, results: Path | None = None, runs: dict[int, Path] | None = None, eval_sets: int = 5
) -> Path:
    """Reliability of relative surprise vs training-set size (paper Figure 3), as a PNG.

    Args:
        out: PNG to write.
        results: sweep.json written by analyze sweep.
        runs: instead of results, tested runs (with voe_report/pairs.csv) by training-set
            size, e.g. {100: runs/size_100, 1000: runs/size_1000}.
        eval_sets: with runs, evaluation sets per run.
    """
    if (results is None) == (runs is None):
        raise ValueError("give either results (a sweep.json) or runs (SIZE: RUN_DIR), not both")
    if results is not None:
        rows = json.loads(Path(results).read_text())
    else:
        assert runs is not None  # exactly one of results and runs, checked above
        rows = []
        for size, run_dir in runs.items():
            pairs = trained_reports(run_dir, "pairs.csv")
            if not pairs:
                raise FileNotFoundError(f"no voe_report/pairs.csv under {run_dir} (run test first)")
            rows.extend(
                sweep_rows(
                    PairResults.from_csv(pairs[-1]),
                    size,
                    eval_sets,
                    alpha=_report_alpha(pairs[-1].parent),
                )
            )
    return save_figure(size_sweep_figure(rows), out)
