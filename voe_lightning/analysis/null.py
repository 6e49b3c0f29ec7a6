"""The untrained null of a model family (docs/architecture.md §6): what copies of the same
network at initialization score on the same probes, so a trained result can be read against
it. Garrido et al. (2025) report every model beside 20 untrained seeds of its network; here an
untrained network reached t = +12 on a difference of 0.03 nats, and the positive control's given
priors pass concepts before any training, so a verdict alone cannot say what training added.

``untrained_null`` (``python -m voe_lightning analyze null``) tests ``seeds`` initializations
of a config's model (``seed_everything`` = 0, 1, ...; learned parts at initialization, given
structure as configured) with the config's test probes and report callback, each report in its
own folder, then tables per concept/variant the distribution of t over initializations, the
share significant and, per concept, the share with a VOE verdict; a trained run's t gets its
percentile in that distribution, and the plot (``null_figure``) shows each t against the
critical t at alpha. ``priors_alone`` is one such initialization of a run's own
config at its own seed, which ``test`` runs first (``priors_alone_first``) where the report
callback asks for it (``VOEReportCallback(priors_alone=True)``, the positive control's config).
A family whose every draw is one function (``distinct_functions``: its predicting heads started
at zero) is drawn again with noise (``add_noise``: seeded Gaussian noise on each learned
parameter at the scale of its initialization, ``NOISE_ADVICE`` unless ``--noise`` says), and
the table says so: one function tests nothing.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np
import scipy.stats
import yaml
from lightning.pytorch.utilities.seed import isolate_rng
from matplotlib.figure import Figure

from voe_lightning.analysis.init_noise import NOISE_ADVICE, NOISE_RULE, NothingToNoise, add_noise
from voe_lightning.callbacks.outcomes import report_folders
from voe_lightning.callbacks.report import VOEReportCallback
from voe_lightning.data.store import write_whole
from voe_lightning.report.figures import save_figure
from voe_lightning.report.priors_alone import PRIORS_ALONE
from voe_lightning.report.summary_file import read_summary
from voe_lightning.runs import fresh_config_name
from voe_lightning.stats.statistics_format import format_number


def _untrained_report(
    build_cli: Callable[[list[str]], Any],
    configs: Sequence[Path],
    seed: int,
    out: Path,
    extra_args: Sequence[str],
    noise: float = 0.0,
) -> Path:
    """Test the configs' model at initialization under ``seed``, with ``add_noise`` at
    ``noise`` (0: none) once it is built and before the test; its report's folder."""
    arguments = [word for config in configs for word in ("--config", str(config))]
    cli = build_cli(
        [
            *arguments,
            "--seed_everything",
            str(seed),
            "--trainer.logger.init_args.save_dir",
            str(out),
            "--trainer.logger.init_args.name",
            f"seed_{seed}",
            *extra_args,
        ]
    )
    if noise and not add_noise(cli.model, noise, seed):
        raise NothingToNoise(
            f"--noise {noise:g} changes nothing: {type(cli.model).__name__} has no learned "
            "parameter, so its initializations are one function; give --noise 0"
        )
    cli.trainer.test(cli.model, datamodule=cli.datamodule)
    reports = report_folders(cli.trainer.callbacks)
    if not reports:
        raise ValueError(
            "the configs' trainer wrote no report: add "
            "voe_lightning.callbacks.VOEReportCallback to its callbacks"
        )
    return reports[-1]


def priors_alone(
    build_cli: Callable[[list[str]], Any], config: Mapping[str, Any], seed: int, out: Path
) -> dict[str, Any]:
    """What a model's given structure scores before any training: the run's whole ``config``
    (a plain dict, as saved; model arguments as tested) at initialization under the run's
    ``seed``, tested on the same probes (``_untrained_report``: one initialization of the
    null), its config and report under ``out`` (a new logger version each time). Returns
    that report's summary.json document with its ``seed`` and ``report`` folder."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    config_path = out / fresh_config_name(out, "config")
    write_whole({config_path: yaml.safe_dump(dict(config), sort_keys=False)})
    report = _untrained_report(
        build_cli, [config_path], seed, out, ["--trainer.logger.init_args.version", "null"]
    )
    return {**read_summary(report), "seed": seed, "report": str(report)}


def priors_alone_first(
    callbacks: Sequence[VOEReportCallback],
    build_cli: Callable[[list[str]], Any],
    config: Mapping[str, Any],
    seed: Any,
    out: Path,
) -> None:
    """Before a ``test`` whose report ``callbacks`` ask for ``priors_alone``: its ``config`` as
    tested, at initialization under the run's ``seed`` (an integer), tested first on the same
    probes into ``out`` (``priors_alone``) and handed to each callback for its report; the
    test's random state is kept as it was."""
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ValueError(
            f"priors_alone tests the config at initialization under the run's "
            f"seed, and seed_everything is {seed!r}: give an integer"
        )
    print(
        f"test: first the config at initialization (seed {seed}) on the same probes, "
        f"its {PRIORS_ALONE} rows for the report, into {out}"
    )
    with isolate_rng():
        untrained = priors_alone(build_cli, config, seed, out)
    for callback in callbacks:
        callback.untrained = untrained


#: What a report's ``source`` says of its probes; a trained t is placed only among t's of the same.
PROBE_SOURCE = ("data_root", "seed_offset", "probe_split", "probe_root")


def _same_source(key: str, one: Any, other: Any) -> bool:
    """Whether two reports' ``source`` values of ``key`` agree (paths as written or resolved)."""
    if one == other or not key.endswith("root") or None in (one, other):
        return cast(bool, one == other)
    return os.path.normpath(one) == os.path.normpath(other) or (
        Path(one).resolve() == Path(other).resolve()
    )


def check_same_probes(null: Mapping[str, Any], trained: Mapping[str, Any], where: Any) -> None:
    """Refuse a ``trained`` summary tested on other probes than an untrained ``null`` one: its
    data root, probe store, seed offset or split (what both ``source``s name) or a row's n (t
    grows as sqrt(n)), naming both; its t among theirs would be no percentile of anything."""
    ours, theirs = null.get("source") or {}, trained.get("source") or {}
    advice = (
        "a trained t is placed only among untrained t's on the same probes: test the run "
        "with the null's data and seed offset, or give them to the null (--extra_args)"
    )
    for key in PROBE_SOURCE:
        if key in ours and key in theirs and not _same_source(key, ours[key], theirs[key]):
            raise ValueError(
                f"--trained {where} was tested on other probes than the untrained "
                f"initializations: its {key} is {theirs[key]!r}, theirs {ours[key]!r}; {advice}"
            )
    sizes = {(row["concept"], row["variant"]): row.get("n") for row in null["rows"]}
    for row in trained["rows"]:
        size = sizes.get((row["concept"], row["variant"]))
        if row.get("t") is not None and None not in (size, row.get("n")) and size != row["n"]:
            raise ValueError(
                f"--trained {where} was tested on other probes than the untrained "
                f"initializations: its {row['concept']}/{row['variant']} has n = {row['n']}, "
                f"theirs n = {size}, and t grows as sqrt(n); {advice}"
            )


def _percentile(value: float, null: np.ndarray) -> float:
    """Share of the null values below ``value``, ties counting half (in percent)."""
    return float(100 * ((null < value).mean() + 0.5 * (null == value).mean()))


def null_rows(
    summaries: Sequence[Mapping[str, Any]], trained: Mapping[str, Any] | None = None
) -> list[dict[str, Any]]:
    """Per concept/variant of the untrained ``summaries`` (report summary.json documents, one
    per initialization): how many were tested, t's median, minimum and maximum, the share
    significant, the concept's share of VOE verdicts and, given a ``trained`` summary, its t and
    that t's percentile among the untrained ones (ties half)."""
    t_values: dict[tuple[str, str], list[float]] = {}
    significant: dict[tuple[str, str], list[bool]] = {}
    voe: dict[str, list[bool]] = {}
    for summary in summaries:
        for row in summary["rows"]:
            if row.get("t") is not None:
                key = (row["concept"], row["variant"])
                t_values.setdefault(key, []).append(float(row["t"]))
                significant.setdefault(key, []).append(bool(row["significant"]))
        for verdict in summary["verdicts"]:
            voe.setdefault(verdict["concept"], []).append(bool(verdict["voe"]))
    trained_t = {
        (row["concept"], row["variant"]): row.get("t") for row in (trained or {}).get("rows", [])
    }
    rows = []
    for (concept, variant), values in t_values.items():
        null = np.asarray(values)
        defined = null[~np.isnan(null)]  # every d = 0 leaves t undefined: no place in the spread
        median, low, high = (
            (np.median(defined), defined.min(), defined.max()) if defined.size else (math.nan,) * 3
        )
        row = {
            "concept": concept,
            "variant": variant,
            "initializations": null.size,
            "undefined": int(null.size - defined.size),
            "t_median": float(median),
            "t_min": float(low),
            "t_max": float(high),
            "significant_share": float(np.mean(significant[concept, variant])),
            "voe_share": float(np.mean(voe.get(concept, [False]))),
        }
        if trained_t.get((concept, variant)) is not None:
            row["trained_t"] = float(trained_t[concept, variant])
            row["trained_percentile"] = _percentile(row["trained_t"], defined)
        rows.append(row)
    return rows


def distinct_functions(reports: Sequence[Path]) -> int:
    """How many different functions the initializations behind ``reports`` (their voe_report
    folders) are on the probes: the number of different pairs.csv files (every pair's
    per-frame surprise, written in full precision)."""
    return len({hashlib.sha256((Path(r) / "pairs.csv").read_bytes()).digest() for r in reports})


def one_function(rows: list[dict[str, Any]]) -> None:
    """Take the trained percentile out of ``rows`` of a null whose initializations are one
    function: a t among copies of one value is no percentile of anything. In place."""
    for row in rows:
        if "trained_percentile" in row:
            row["trained_percentile"] = None


def format_null(
    rows: Sequence[Mapping[str, Any]],
    alpha: float,
    distinct: int | None = None,
    noise: float = 0.0,
    redrawn: bool = False,
) -> str:
    """``null_rows`` as a Markdown table with a line saying what the columns are (and the
    ``noise`` the initializations were given, ``add_noise``; ``redrawn``: because without it
    they were one function) and, given ``distinct`` (``distinct_functions``), how many
    different functions the initializations are: where one, that the null tests nothing."""
    lines = [
        "| concept | variant | inits | t median [min, max] | significant | concept VOE "
        "| trained t | percentile |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        spread = (
            f"{format_number(row['t_median'], '+.2f')} [{format_number(row['t_min'], '+.2f')}"
            f", {format_number(row['t_max'], '+.2f')}]"
        ) + (f", {row['undefined']} undefined" if row.get("undefined") else "")
        lines.append(
            f"| {row['concept']} | {row['variant']} | {row['initializations']} "
            f"| {spread} | {row['significant_share']:.0%} | {row['voe_share']:.0%} "
            f"| {format_number(row.get('trained_t'), '+.2f')} "
            f"| {format_number(row.get('trained_percentile'), '.0f')} |"
        )
    lines += [
        "",
        "Untrained initializations of one config"
        + (f", each with noise {noise:g} (--noise: {NOISE_RULE})," if noise else "")
        + " tested on the same probes: t of "
        f"the one-tailed paired test per initialization; significant: share with p < "
        f"{alpha:g}; concept VOE: share of initializations whose verdict for the concept "
        "is VOE; percentile: where the trained run's t falls among the untrained ones "
        "(ties half); undefined: initializations whose every difference was 0, left out of "
        "the spread and the percentile.",
    ]
    count = rows[0]["initializations"] if rows else 0
    if redrawn:
        lines += [
            "",
            f"Without noise the {count} initializations scored every pair alike: one function "
            "(the family starts from it at every seed, e.g. predicting layers started at zero), "
            f"which tests nothing; so these rows are the initializations drawn again with noise "
            f"{noise:g}.",
        ]
    if distinct is not None and distinct < 2 <= count and not noise:
        lines += [
            "",
            f"**All {count} initializations score every pair alike: they are one function, "
            "and this null tests nothing** (the model has no learned parameter, e.g. a "
            "follower, so no noise makes them differ). Read a trained run against the "
            "followers of its own inputs instead (its report's cues.md).",
        ]
    elif distinct is not None and distinct < 2 <= count:
        lines += [
            "",
            f"**All {count} initializations, even with noise {noise:g}, score every pair "
            "alike: they are one function, and this null tests nothing** (the noise changes "
            "learned parameters only, and none reaches this model's surprise, e.g. a "
            "follower's). Read a trained run against the followers of its own inputs instead "
            "(its report's cues.md).",
        ]
    elif distinct is not None:
        lines += ["", f"{distinct} of {count} initializations are different functions."]
    return "\n".join(lines) + "\n"


def _null_points(
    document: Mapping[str, Any], concept: str, variant: str
) -> tuple[np.ndarray, float]:
    """The finite t of ``concept``/``variant`` at each initialization of a null.json
    ``document``, and the median of their df."""
    rows = [
        row
        for initialization in document["initializations"]
        for row in initialization["rows"]
        if (row["concept"], row["variant"]) == (concept, variant) and row.get("t") is not None
    ]
    t = np.asarray([float(row["t"]) for row in rows])
    df = np.asarray([float(row["df"]) for row in rows if row.get("df") is not None])
    return t[np.isfinite(t)], float(np.median(df)) if df.size else math.nan


def null_figure(document: Mapping[str, Any], alpha: float) -> Figure:
    """The null drawn: a row per concept/variant of a null.json ``document``, the untrained
    initializations' t as points (jittered up and down, non-finite ones left out), the
    one-tailed critical t at ``alpha`` for the row's df (``scipy.stats.t``) as a dashed mark,
    and a trained run's t as a diamond where the row holds one."""
    rows = document["rows"]
    figure = Figure(figsize=(7.5, 1.5 + 0.4 * len(rows)), layout="constrained")
    ax = figure.subplots()
    jitter, trained = (
        np.random.default_rng(0),
        [row for row in rows if math.isfinite(row.get("trained_t", math.nan))],
    )
    for index, row in enumerate(rows):
        t, df = _null_points(document, row["concept"], row["variant"])
        ax.scatter(
            t,
            index + jitter.uniform(-0.2, 0.2, t.size),
            s=14,
            color="0.45",
            alpha=0.8,
            label="untrained initializations" if index == 0 else None,
        )
        ax.plot(
            [scipy.stats.t.ppf(1 - alpha, df)] * 2,
            [index - 0.35, index + 0.35],
            "k--",
            lw=1.2,
            label=f"critical t (one-tailed, α = {alpha:g})" if index == 0 else None,
        )
        if row in trained:
            ax.scatter(
                [row["trained_t"]],
                [index],
                marker="D",
                s=40,
                color="C3",
                zorder=3,
                label="trained" if row is trained[0] else None,
            )
    ax.set_yticks(range(len(rows)), [f"{row['concept']} / {row['variant']}" for row in rows])
    ax.set_ylim(len(rows) - 0.5, -0.5)
    ax.axvline(0, color="0.8", lw=0.8, zorder=0)
    ax.set_xlabel("t of the one-tailed paired test (inconsistent > consistent)")
    ax.set_title(  # two lines: the configs' names alone can fill the width
        f"Untrained null: {document['seeds']} initializations"
        + (f", noise {document['noise']:g}" if document.get("noise") else "")
        + f"\n{', '.join(Path(config).name for config in document['configs'])}"
    )
    figure.legend(loc="outside lower center", ncols=3, fontsize="small", frameon=False)
    return figure


def untrained_null(
    configs: list[Path],
    seeds: int = 20,
    out: Path = Path("runs/null"),
    trained: Path | None = None,
    extra_args: list[str] | None = None,
    noise: float = 0.0,
    _build_cli: Callable[[list[str]], Any] | None = None,
) -> str:
    """Test untrained initializations of a config's model on its test probes and table the
    distribution of each concept's statistic and verdict (module docstring); writes
    ``out/null.json`` (every initialization's rows and verdicts), ``out/null.md`` and
    ``out/null.png`` (``null_figure``, its path printed).

    Args:
        configs: the test configs, in order, after base.yaml (e.g. configs/vrnn_quickstart.yaml),
            with VOEReportCallback in the callbacks.
        seeds: initializations (seed_everything 0 .. seeds - 1).
        out: folder of the runs and the table.
        trained: a trained run's report directory (its voe_report) to place in the null,
            tested on the same probes (``check_same_probes``: refused otherwise).
        extra_args: further arguments for every initialization's run, e.g. a smaller test set.
        noise: Gaussian noise added to each initialization's learned parameters before its
            test, seeded by its seed, in units of each tensor's initialization scale (its
            own sd, or 1/sqrt(3 fan-in) where that is 0); 0: none, unless the draws are one
            function (heads started at zero): then they are drawn again with NOISE_ADVICE
            (1.0) under ``out/noise_1``. Refused for a model with no learned parameter.
        _build_cli: builds a run's model, data and trainer from arguments without running it;
            the CLI passes its own, so this module does not import the CLI.
    """
    if _build_cli is None:
        raise TypeError(
            "untrained_null builds its runs through _build_cli: run it as `python -m "
            "voe_lightning analyze null`"
        )
    if seeds < 1:
        raise ValueError(f"seeds must be at least 1, got {seeds}")
    if not (math.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be a finite number of at least 0, got {noise}")
    out = Path(out)
    trained_summary = None if trained is None else read_summary(trained)

    def draw(folder: Path, scale: float) -> tuple[list[Path], list[dict[str, Any]]]:
        reports, summaries = [], []
        for seed in range(seeds):
            reports.append(
                _untrained_report(_build_cli, configs, seed, folder, extra_args or (), scale)
            )
            summaries.append(read_summary(reports[-1]))
            if trained_summary is not None and seed == 0:  # refused before the other seeds run
                check_same_probes(summaries[0], trained_summary, trained)
        return reports, summaries

    reports, summaries = draw(out, noise)
    distinct = distinct_functions(reports)
    redrawn = distinct == 1 and seeds >= 2 and not noise
    if redrawn:
        folder = out / f"noise_{NOISE_ADVICE:g}"
        print(
            f"the {seeds} initializations are one function (every pair scored alike): drawing "
            f"them again with noise {NOISE_ADVICE:g} into {folder}"
        )
        try:
            reports, summaries = draw(folder, NOISE_ADVICE)
            noise, distinct = NOISE_ADVICE, distinct_functions(reports)
        except NothingToNoise:  # a follower: no draw can differ
            redrawn = False
    rows = null_rows(summaries, trained_summary)
    if distinct == 1:
        one_function(rows)
    table = format_null(rows, summaries[0]["alpha"], distinct, noise, redrawn)
    document = {
        "configs": [str(c) for c in configs],
        "seeds": seeds,
        **({"noise": noise} if noise else {}),  # none: null.json as before --noise
        **({"redrawn_with_noise": True} if redrawn else {}),
        "distinct_functions": distinct,
        "rows": rows,
        "initializations": [
            {"seed": seed, "rows": s["rows"], "verdicts": s["verdicts"]}
            for seed, s in enumerate(summaries)
        ],
    }
    write_whole({out / "null.json": json.dumps(document, indent=2) + "\n", out / "null.md": table})
    print(table, end="")
    save_figure(null_figure(document, summaries[0]["alpha"]), out / "null.png")
    return table
