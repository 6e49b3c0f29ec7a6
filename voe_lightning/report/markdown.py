"""summary.md's text: its first line naming the report's source (``format_source``), the rows
as a Markdown table with their notes and legend (``format_markdown``) and each concept's verdict
under the causality check (``format_verdicts``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from voe_lightning.model.vrnn_lru import VRNNLRUModel
from voe_lightning.stats.causality import Causality
from voe_lightning.stats.statistics_format import format_alpha, row_text, rows_alpha
from voe_lightning.stats.surprise_window import SurpriseWindow
from voe_lightning.stats.verdicts import Verdict

#: What a frame's surprise is unless told otherwise: the paper's (the VRNN-LRU's).
VRNN_SURPRISE = VRNNLRUModel.SURPRISE


def format_verdicts(verdicts: Sequence[Verdict], causality: Causality | None = None) -> list[str]:
    """Markdown lines of the ``causality`` check and each concept's VOE verdict (computed
    once by the report, ``verdicts.concept_verdicts``, withheld when the check failed)."""
    lines = [causality.line(), ""] if causality is not None else []
    for verdict in verdicts:
        text = "**VOE**" if verdict.voe else verdict.text()
        line = f"- {verdict.concept}: {text} (rule: {verdict.rule})"
        if verdict.halves:
            both = "both significant" if verdict.halves_significant else "not both significant"
            line += f"; halves on their own ({both}): {verdict.halves}"
        lines.append(line)
    return lines


def format_markdown(
    rows: Sequence[Mapping[str, Any]],
    verdicts: Sequence[Verdict],
    surprise: str = VRNN_SURPRISE,
    window: SurpriseWindow = SurpriseWindow(),
    causality: Causality | None = None,
) -> str:
    """The summary as a Markdown table (paper notation, alpha in its header), notes as
    footnotes below it, then the ``causality`` check and each concept's VOE verdict (the
    report's ``verdicts`` of these rows);
    ``surprise`` names what a frame's surprise is, ``window`` the frames a video's surprise
    sums."""
    alpha = rows_alpha(rows)
    header = (
        f"| concept | variant | n | M [95% CI] | t(df) | p | sig. ({format_alpha(alpha)}) "
        "| d_z [95% CI] | accuracy | AUROC | halves M |"
    )
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    notes = []
    for row in rows:
        marker = ""
        if row.get("note"):
            notes.append(row["note"])
            marker = f" [{len(notes)}]"
        text = row_text(row)
        lines.append(
            f"| {row['concept']} | {row['variant']}{marker} | {text.n} | {text.mean_interval} "
            f"| {text.t} | {text.p} | {text.sig} | {text.d_z_interval} | {text.accuracy} "
            f"| {text.auroc} | {text.halves} |"
        )
    lines.append("")
    frames = (
        "frames"
        if window.all_frames
        else f"the {window.describe()} (the first frame at which its two videos differ)"
    )
    lines.append(
        "M: mean relative surprise d = S(inconsistent) - S(consistent), S = sum over "
        f"{frames} of {surprise}; one-tailed paired t-test, H1: M > 0; "
        f"sig.: p < {alpha:g} (* as in the paper); accuracy: share of pairs "
        "with d > 0; pooled: the stratified test of a concept's standard and "
        "counterbalanced pairs, M the mean of the two variants' M, its SE from both, "
        "Welch-Satterthwaite df; its d_z is M over the SD of d of all its pairs; "
        "quadruplet (unchangeableness: one per change, <change>_quadruplet): per seed "
        "D = [S(AB) - S(A)] + [S(BA) - S(B)] over its first-half (A, AB) and "
        "second-half, counterbalanced (B, BA) pairs, whose inconsistent videos hold "
        "exactly the consistent ones' frames after the change; M, t and accuracy "
        "of D, halves M: the means of S(AB) - S(A) / S(BA) - S(B)."
    )
    lines.extend(f"[{i}] {note}" for i, note in enumerate(notes, start=1))
    lines += [
        "",
        f"Verdicts: a concept with quadruplets shows VOE only when each of its "
        f"quadruplet tests is significant (p < {alpha:g}) with both halves' M above 0; another "
        "only when its pooled test and each of its two variants are significant; "
        "without a counterbalanced pair, when every probe variant is. Generalization "
        "variants do not enter.",
        "",
    ]
    lines += format_verdicts(verdicts, causality)
    return "\n".join(lines) + "\n"


def format_source(source: Mapping[str, Any]) -> str:
    """summary.md's first line, from the report's ``source``: the checkpoint tested (and its
    step) and the store its probes come from with their seed offset, so a re-test on fresh
    probes says so where it is read; '' where ``source`` names neither."""
    parts = []
    if source.get("checkpoint"):
        step = source.get("global_step")
        parts.append(
            f"checkpoint {source['checkpoint']}" + (f" (step {step})" if step is not None else "")
        )
    where = source.get("probe_root") or source.get("data_root")
    if where:
        offset = source.get("seed_offset")
        split = "the validation probes" if source.get("probe_split") == "val" else "the probes"
        parts.append(
            f"{split} of {where}" + (f" (seed offset {offset})" if offset is not None else "")
        )
    return f"Tested: {'; '.join(parts)}.\n\n" if parts else ""
