"""The report's rows of its model's given structure alone, the untrained copy that
``null.priors_alone`` tests first: summary.json's ``priors_alone`` (``priors_alone_document``)
and its section of summary.md beside the trained rows (``format_priors_alone``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from voe_lightning.stats.statistics_format import format_t, rows_alpha

#: The label of a report's rows of its model's given structure alone (``null.priors_alone``).
PRIORS_ALONE = "priors alone (untrained)"
#: The columns of each of those rows summary.json keeps.
PRIORS_ALONE_COLUMNS = (
    "concept",
    "variant",
    "n",
    "relative_surprise",
    "t",
    "df",
    "p_value",
    "significant",
)


def priors_alone_document(untrained: Mapping[str, Any]) -> dict[str, Any]:
    """summary.json's ``priors_alone``: of the ``untrained`` copy's summary (its report's
    summary.json with ``seed`` and ``report``, ``null.priors_alone``), each row's test and
    each concept's verdict, labelled ``PRIORS_ALONE``."""
    return {
        "label": PRIORS_ALONE,
        "seed": untrained["seed"],
        "report": untrained["report"],
        "rows": [{key: row.get(key) for key in PRIORS_ALONE_COLUMNS} for row in untrained["rows"]],
        "verdicts": untrained["verdicts"],
    }


def format_priors_alone(
    rows: Sequence[Mapping[str, Any]],
    verdicts: Sequence[Mapping[str, Any]],
    priors: Mapping[str, Any],
) -> str:
    """summary.md's section of ``priors`` (``priors_alone_document``) beside the trained
    ``rows`` and ``verdicts`` (as summary.json holds them): t per concept/variant both ways,
    then each concept's verdict both ways, so a reader sees which passes the training added."""
    untrained = {(row["concept"], row["variant"]): row for row in priors["rows"]}
    lines = [
        f"## {PRIORS_ALONE.capitalize()}",
        "",
        f"The same config with its learned parts at initialization (seed {priors['seed']}) "
        "and its given structure as configured, tested on the same probes: what the given "
        f"priors score before any training (its whole report: {priors['report']}).",
        "",
        f"| concept | variant | t trained | t {PRIORS_ALONE} |",
        "|---|---|---|---|",
    ]
    for row in rows:
        alone = untrained.get((row["concept"], row["variant"]), {})
        lines.append(f"| {row['concept']} | {row['variant']} | {_t_cell(row)} | {_t_cell(alone)} |")
    lines += ["", f"t(df) of the one-tailed paired test, * where p < {rows_alpha(rows):g}.", ""]
    alone = {verdict["concept"]: verdict["verdict"] for verdict in priors["verdicts"]}
    lines += [
        f"- {verdict['concept']}: trained {verdict['verdict']}; {PRIORS_ALONE} "
        f"{alone.get(verdict['concept'], 'n/a')}"
        for verdict in verdicts
    ]
    return "\n".join(lines) + "\n"


def _t_cell(row: Mapping[str, Any]) -> str:
    """A row's t(df), starred where significant ('n/a' for no row or no test)."""
    return format_t(row.get("t"), row.get("df")) + ("*" if row.get("significant") else "")
