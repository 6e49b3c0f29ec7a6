"""The cue audit written out (docs/architecture.md §8): the compact table of each cue's
accuracy / d_z beside the model's (Markdown for summary and cues.md, rich for the terminal), the
tables of how the model's surprise, and a physics-perfect observer's, correlate with each cue
pair by pair, the files cues.md, cues.csv, cue_correlations.csv,
physics_perfect_correlations.csv and cues.json, and ``python -m voe_lightning audit``. The scores
and their tests are ``voe_lightning.audit.cues``; each cell's numbers are written by
``statistics_format.row_text``, as every statistics table's are."""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from voe_lightning import specs
from voe_lightning.audit.cues import (
    CORRELATION_COLUMNS,
    CUE_COLUMNS,
    CUE_TITLES,
    PHYSICS_PERFECT,
    audit_split,
)
from voe_lightning.audit.followers import follower_title
from voe_lightning.audit.video_cues import CUES
from voe_lightning.data.store import write_whole
from voe_lightning.stats import statistics, verdicts
from voe_lightning.stats.statistics_format import (
    BRIEF,
    format_alpha,
    json_row,
    row_text,
    rows_alpha,
)

if TYPE_CHECKING:
    from rich.table import Table

__all__ = [
    "audit",
    "cue_table",
    "format_correlations",
    "format_followers",
    "followers_passing",
    "passing_sentence",
    "format_markdown",
    "format_physics_perfect",
    "write_audit",
]

#: Concepts where a follower's pass is the concept itself (attribute memory), marked ‡.
CONCEPT_ITSELF = ("unchangeableness",)
#: How a compact table's cell writes accuracy and d_z: '61% / +0.52'.
CELL_STYLE = replace(BRIEF, d_z="+.2f")
#: The rows a concept's verdict may read, printed bold: its pooled and quadruplet tests.
_TESTED_TOGETHER = frozenset({statistics.POOLED}) | specs.QUADRUPLET_ROWS


def _cell(row: Mapping[str, Any] | None) -> tuple[str, bool]:
    """'acc% / d_z' of a row, and whether it separates the pairs (p_two_sided or p < alpha)."""
    if row is None or row.get("accuracy") is None:
        return "n/a", False
    text = row_text(row, CELL_STYLE)
    separates = row["p_two_sided"] < row["alpha"] if "p_two_sided" in row else row["significant"]
    return f"{text.accuracy} / {text.d_z}", bool(separates)


def cue_title(cue: str) -> str:
    """A cue's column title: the pixel cues' short names, a follower's 'states: stay put'."""
    return CUE_TITLES[cue] if cue in CUE_TITLES else follower_title(cue)


def follower_names(cue_rows: Sequence[Mapping[str, Any]]) -> tuple[str, ...]:
    """The followers among ``cue_rows``' cues (``audit.followers``), in order."""
    return tuple(dict.fromkeys(r["cue"] for r in cue_rows if r["cue"] not in CUES))


def _table_cells(
    cue_rows: Sequence[Mapping[str, Any]],
    model_rows: Sequence[Mapping[str, Any]] | None,
    cues: Sequence[str] = CUES,
) -> list[tuple[str, str, int, list[tuple[str, bool]]]]:
    """(concept, variant, n, cells) per group: the model's cell first when given, then one
    cell per cue of ``cues``."""
    by_key = {(r["concept"], r["variant"], r["cue"]): r for r in cue_rows}
    models = {(r["concept"], r["variant"]): r for r in model_rows or ()}
    table = []
    for concept, variant in dict.fromkeys((r["concept"], r["variant"]) for r in cue_rows):
        cells = [_cell(models.get((concept, variant)))] if model_rows is not None else []
        cells += [_cell(by_key.get((concept, variant, cue))) for cue in cues]
        n = by_key[(concept, variant, cues[0])]["n"]
        table.append((concept, variant, n, cells))
    return table


def format_markdown(
    cue_rows: Sequence[Mapping[str, Any]],
    model_rows: Sequence[Mapping[str, Any]] | None = None,
    title: str = "Cue audit",
    cues: Sequence[str] = CUES,
) -> str:
    """The compact cue table as Markdown: per concept/variant (and pooled), accuracy / d_z of
    each cue of ``cues``, beside the model's when ``model_rows`` (report summary rows) are
    given. Cue cells that separate the pairs (two-sided p < alpha) are bold; model cells with
    one-tailed p < alpha carry *. Notes (skipped cues, degenerate tests) follow the table, the
    cells where every d = 0 counted in one line (a frame-local cue's quadruplet rows are so by
    construction)."""
    model = model_rows is not None
    header = (
        ["concept", "variant", "n"]
        + (["model (surprise)"] if model else [])
        + [cue_title(cue) for cue in cues]
    )
    cue_rows = [r for r in cue_rows if r["cue"] in cues]
    alpha = rows_alpha(cue_rows)
    lines = [
        f"## {title} ({format_alpha(alpha)})",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for concept, variant, n, cells in _table_cells(cue_rows, model_rows, cues):
        texts = []
        for index, (text, separates) in enumerate(cells):
            if model and index == 0:
                texts.append(text + (" *" if separates else ""))
            else:
                texts.append(f"**{text}**" if separates else text)
        name = f"**{variant}**" if variant in _TESTED_TOGETHER else variant
        lines.append(f"| {concept} | {name} | {n} | " + " | ".join(texts) + " |")
    lines += [
        "",
        "Each cell: accuracy / d_z of d = score(inconsistent) - score(consistent) on "
        "the same pairs (cue accuracy counts ties as half: 50% is chance). Cues are "
        "physics-blind: " + ", ".join(f"{cue_title(c)} = {c}" for c in cues) + ". "
        f"**Bold**: the cue separates the pairs (two-sided p < {alpha:g}), so a model "
        "could do as well without physics."
        + (
            f" Model: accuracy / d_z of surprise, * one-tailed p < {alpha:g}; pooled rows "
            "(cues' too) are the stratified test of the two variants."
            if model
            else " Pooled rows are the stratified test of the two variants."
        )
        + " Full statistics in cues.csv.",
    ]
    noted = [r for r in cue_rows if r.get("note") and "bootstrap" not in r["note"]]
    ties = [r for r in noted if "every d = 0" in r["note"]]
    lines += [
        f"- {r['concept']}/{r['variant']}, {cue_title(r['cue'])}: {r['note']}"
        for r in noted
        if r not in ties
    ]
    if ties:
        by_construction = any(r["variant"] in specs.QUADRUPLET_ROWS for r in ties)
        lines.append(
            f"- {len(ties)} cells score both videos of every pair alike (every d = 0: no test, "
            "p set to 1"
            + (
                "; a cue of the frames after the change scores every quadruplet 0 by construction"
                if by_construction
                else ""
            )
            + "); cues.csv has their notes."
        )
    return "\n".join(lines) + "\n"


def followers_passing(cue_rows: Sequence[Mapping[str, Any]]) -> dict[str, list[str]]:
    """Per concept, the followers among ``cue_rows`` that pass it by the verdict's own rule
    (``verdicts.concept_verdicts`` on each follower's rows), in table order."""
    passing: dict[str, list[str]] = {}
    for cue in follower_names(cue_rows):
        rows = [r for r in cue_rows if r["cue"] == cue]
        for verdict in verdicts.concept_verdicts(rows, alpha=rows_alpha(rows)):
            if verdict.voe:
                passing.setdefault(verdict.concept, []).append(cue)
    return passing


def passing_sentence(passing: Mapping[str, Sequence[str]]) -> str:
    """One sentence of ``followers_passing``: which concepts a follower passes, or none."""
    if not passing:
        return "No follower passes any concept by the verdict's rule."
    parts = [
        f"{concept}{' ‡' if concept in CONCEPT_ITSELF else ''} "
        f"({', '.join(cue_title(cue) for cue in cues)})"
        for concept, cues in passing.items()
    ]
    return (
        "**Passed by a follower** (the verdict's rule: quadruplet test significant, both halves "
        f"above 0): {'; '.join(parts)}. A model's VOE there is no evidence of physics."
    )


def format_followers(
    cue_rows: Sequence[Mapping[str, Any]], model_rows: Sequence[Mapping[str, Any]] | None = None
) -> str:
    """The followers' compact table (``format_markdown`` over ``follower_names``) and what a
    bold pooled or quadruplet cell there means; empty without follower rows."""
    names = follower_names(cue_rows)
    if not names:
        return ""
    table = format_markdown(cue_rows, model_rows, "Followers of the model's own inputs", names)
    for concept in CONCEPT_ITSELF:
        table = table.replace(f"| {concept} |", f"| {concept} ‡ |")
    return (
        table
        + (
            "\nFollowers are rules with no dynamics over the inputs the model reads "
            "(`voe_lightning.model.ObjectFollower`: stay put, attributes, seen again, same and seen, "
            "nothing changes, copy last, linear extrapolation); a bold cell says one separates "
            "the pairs, in either direction. ‡ unchangeableness: a memory of each object's "
            "attributes is the concept itself (docs/study/shortcuts.md).\n\n"
        )
        + passing_sentence(followers_passing(cue_rows))
        + "\n"
    )


def _correlation_table(correlation_rows: Sequence[Mapping[str, Any]], title: str) -> list[str]:
    """The lines of a Markdown table of ``CueAudit.model_correlations`` rows: r per
    concept/variant (and pooled) and cue, bold where two-sided p < alpha."""
    by_key = {(r["concept"], r["variant"], r["cue"]): r for r in correlation_rows}
    header = ["concept", "variant", "n"] + [CUE_TITLES[cue] for cue in CUES]
    alpha = rows_alpha(correlation_rows)
    lines = [
        f"## {title} ({format_alpha(alpha)})",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for concept, variant in dict.fromkeys((r["concept"], r["variant"]) for r in correlation_rows):
        cells = []
        for cue in CUES:
            row = by_key[(concept, variant, cue)]
            if row["r"] is None:
                cells.append("n/a")
            else:
                text = f"{row['r']:+.2f}"
                cells.append(f"**{text}**" if row["p_two_sided"] < row["alpha"] else text)
        name = f"**{variant}**" if variant in _TESTED_TOGETHER else variant
        n = by_key[(concept, variant, CUES[0])]["n"]
        lines.append(f"| {concept} | {name} | {n} | " + " | ".join(cells) + " |")
    return lines


def format_correlations(
    correlation_rows: Sequence[Mapping[str, Any]],
    title: str = "Does the model's surprise track a cue, pair by pair?",
) -> str:
    """Markdown table of ``CueAudit.model_correlations``: r per concept/variant (and pooled)
    and cue, bold where two-sided p < alpha, and how to read it."""
    alpha = rows_alpha(correlation_rows)
    lines = _correlation_table(correlation_rows, title)
    lines += [
        "",
        (
            "Each cell: Pearson's r across pairs between the model's relative surprise "
            "S(inconsistent) - S(consistent) and the cue's score(inconsistent) - "
            f"score(consistent); **bold**: two-sided p < {alpha:g}. A model whose pooled "
            "accuracy is at chance but whose r with a cue is large follows that cue in each "
            "variant, and the variants cancel; physics would not depend on the cue. "
            "*Pooled within variants*: r after centring each variant's pairs on their own "
            "means; the pooled r is also large when the model's effect and the cue's merely "
            "differ in size between the variants, physics-perfect or not. "
            "*Within variants, given the seen extent* (records with object states): r after "
            "regressing both, in each variant, on how much of the violation is seen, in "
            "object-frames (seen in one video only; frames until the first; seen, "
            "inconsistent less consistent): a model whose surprise grows with the violation "
            "it sees correlates with the cues that count those frames in pixels, physics or "
            "not; one that follows the pixels still does. "
            "*Physics-perfect observer, within variants* (records with object states): not "
            "the model's r but that of an observer that expects what the consistent video "
            "shows and pays for each object-frame seen in one video only and for how far "
            "apart the states of an object seen in both are: what perfect physics alone gives "
            "on these pairs, the reference to read a model's row against. Full values in "
            "cue_correlations.csv."
        ),
    ]
    return "\n".join(lines) + "\n"


def format_physics_perfect(correlation_rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown table of the physics-perfect observer's correlations with each cue
    (``CueAudit.model_correlations`` of ``CueAudit.physics_perfect``): what perfect physics
    alone gives on a store's probes, per variant and pooled, and how to read it."""
    alpha = rows_alpha(correlation_rows)
    lines = _correlation_table(
        correlation_rows, "What does perfect physics correlate with, pair by pair?"
    )
    lines += [
        "",
        (
            "Each cell: Pearson's r across pairs between a physics-perfect observer's "
            "relative surprise and the cue's score(inconsistent) - score(consistent); "
            f"**bold**: two-sided p < {alpha:g}. The observer (`cues.physics_perfect_surprise`) "
            "expects what the consistent video shows and pays for each object-frame seen in "
            "one video only and for how far apart the states of an object seen in both are. "
            "Perfect physics alone gives these correlations on these probes: a model's (the "
            "`test` report's) are read against them, and a large r within one variant is no "
            "evidence of cue following where the observer's is large too. Full values in "
            "physics_perfect_correlations.csv."
        ),
    ]
    return "\n".join(lines) + "\n"


def cue_table(
    cue_rows: Sequence[Mapping[str, Any]],
    model_rows: Sequence[Mapping[str, Any]] | None = None,
    title: str = "Cue audit",
) -> Table:
    """The compact cue table as a rich Table (separating cue cells red, pooled rows bold)."""
    from rich.table import Table

    alpha = rows_alpha(cue_rows)
    table = Table(
        title=f"{title} ({format_alpha(alpha)})",
        caption="accuracy (ties half) / d_z; red: the cue separates the pairs "
        f"(two-sided p < {alpha:g})",
    )
    for header in (
        ["concept", "variant", "n"]
        + (["model"] if model_rows is not None else [])
        + [CUE_TITLES[cue] for cue in CUES]
    ):
        table.add_column(header, justify="left" if header in ("concept", "variant") else "right")
    groups = _table_cells(cue_rows, model_rows)
    for index, (concept, variant, n, cells) in enumerate(groups):
        styled = []
        for column, (text, separates) in enumerate(cells):
            is_model = model_rows is not None and column == 0
            styled.append(
                text + " *"
                if is_model and separates
                else f"[red]{text}[/red]"
                if separates
                else text
            )
        last = index + 1 == len(groups) or groups[index + 1][0] != concept
        table.add_row(
            concept,
            variant,
            str(n),
            *styled,
            style="bold" if variant in _TESTED_TOGETHER else None,
            end_section=last,
        )
    return table


def write_audit(
    cue_rows: Sequence[Mapping[str, Any]],
    out_dir: str | Path,
    model_rows: Sequence[Mapping[str, Any]] | None = None,
    title: str = "Cue audit",
    correlation_rows: Sequence[Mapping[str, Any]] | None = None,
    physics_perfect_rows: Sequence[Mapping[str, Any]] | None = None,
    **metadata: Any,
) -> Path:
    """Write ``out_dir/cues.md`` (the compact table, beside the model's rows when given, then
    the model-cue correlations and the physics-perfect observer's when given), ``cues.csv``
    (every column of every row), ``cue_correlations.csv`` and
    ``physics_perfect_correlations.csv`` (with those correlations) and ``cues.json`` (rows,
    correlations and ``metadata``), all or none of them (``store.write_whole``: a full
    disk names the file and leaves the previous audit whole)."""
    out = check_out_folder(out_dir, "the audit's folder")
    markdown = format_markdown(cue_rows, model_rows, title)
    if follower_names(cue_rows):
        markdown += "\n" + format_followers(cue_rows, model_rows)
    files = {}
    for rows, formatter, name in (
        (correlation_rows, format_correlations, "cue_correlations"),
        (physics_perfect_rows, format_physics_perfect, "physics_perfect_correlations"),
    ):
        if rows is not None:
            markdown += "\n" + formatter(rows)
            files[out / f"{name}.csv"] = _csv_text(rows, CORRELATION_COLUMNS)
    files[out / "cues.md"] = markdown
    files[out / "cues.csv"] = _csv_text(cue_rows, CUE_COLUMNS)
    document = {
        **metadata,
        "cues": list(CUES + follower_names(cue_rows)),
        "rows": [json_row(row) for row in cue_rows],
    }
    if correlation_rows is not None:
        document["model_correlations"] = [json_row(row) for row in correlation_rows]
    if physics_perfect_rows is not None:
        document["physics_perfect_correlations"] = [json_row(row) for row in physics_perfect_rows]
    files[out / "cues.json"] = json.dumps(document, indent=2) + "\n"
    write_whole(files)
    return out


def check_out_folder(out: str | os.PathLike[str], what: str) -> Path:
    """``out`` as a Path, refused (a ValueError naming it) when it, or the first of its
    parents that exists, is a file: the audit writes several files into a folder."""
    out = Path(out)
    existing = next((path for path in (out, *out.parents) if path.exists()), None)
    if existing is not None and not existing.is_dir():
        where = "is a file" if existing == out else f"lies under the file {existing}"
        raise ValueError(
            f"{what} {out} {where}; it is a folder the audit writes cues.md, cues.csv, "
            "cues.json and the correlation CSVs into: give a folder (new or existing)"
        )
    return out


def _csv_text(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> str:
    """``rows`` as CSV text with a header of ``columns``."""
    handle = io.StringIO(newline="")
    writer = csv.DictWriter(handle, fieldnames=columns)
    writer.writeheader()
    writer.writerows(rows)
    return handle.getvalue()


def audit(
    root: Path,
    split: Literal["val", "test", "generalization"] = "test",
    concepts: list[specs.Concept] | None = None,
    out: Path | None = None,
    *,
    alpha: float,
    batch_size: int = 64,
    num_workers: int = 0,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Physics-blind cue scores of a probe split, with the model's paired statistics.

    Prints the table (M, t, p, d_z, accuracy and pooled rows per cue) and writes cues.md,
    cues.csv and cues.json; where the records carry object states, also what a physics-perfect
    observer's surprise correlates with (cues.md, physics_perfect_correlations.csv), the
    reference for a model's correlations; returns the rows.

    Args:
        root: dataset folder (a generated store).
        split: probe split to audit.
        concepts: concepts to audit (default: every concept in the store).
        out: output folder (default: ROOT/cue_audit/SPLIT).
        alpha: significance level (default: configs/base.yaml's alpha).
        batch_size: pairs scored at once.
        num_workers: data loader worker processes.
        progress: show a progress bar.
    """
    from rich.console import Console

    statistics.check_alpha(alpha)
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if out is not None:
        check_out_folder(out, "--out")
    scores = audit_split(root, split, concepts, batch_size, num_workers, progress=progress)
    rows = scores.rows(alpha=alpha)
    reference = None
    if scores.physics_perfect is not None:  # its own row of the report is its within-variants r
        reference = [
            row
            for row in scores.model_correlations(scores.physics_perfect, alpha=alpha)
            if row["variant"] != PHYSICS_PERFECT
        ]
    title = f"Cue audit of {root} ({split} split, {len(scores)} pairs)"
    out = write_audit(
        rows,
        out or Path(root) / "cue_audit" / split,
        title=title,
        root=str(root),
        split=split,
        alpha=alpha,
        num_pairs=len(scores),
        physics_perfect_rows=reference,
    )
    console = Console()
    if not console.is_terminal:  # logs and pipes: do not cut the table at 80 columns
        console.width = 140
    console.print(cue_table(rows, title=title))
    extra = ", physics_perfect_correlations.csv" if reference is not None else ""
    print(f"cue audit written to {out} (cues.md, cues.csv, cues.json{extra})")
    return rows
