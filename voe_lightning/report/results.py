"""The report's numbers: per-pair probe results (``PairResults``, pairs.csv), the paired test per
concept/variant (``summarize``), the field's metric set beside it (``field_metric_rows``) and
the summary tables (summary.json, summary.csv, summary.md)."""

from __future__ import annotations

import csv
import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from voe_lightning.causality import Causality, check_prefix
from voe_lightning.model.vrnn_lru import VRNNLRUModel
from voe_lightning.specs import CONCEPTS, VARIANTS
from voe_lightning.stats.field_metrics import field_metrics, format_field_metrics
from voe_lightning.stats.statistics import (
    ALPHA,
    QUADRUPLET_ROWS,
    QuadrupletTestResult,
    group_test,
    untested_reason,
)
from voe_lightning.stats.statistics_format import (
    format_alpha,
    format_t,
    json_row,
    row_text,
    rows_alpha,
)
from voe_lightning.stats.surprise_window import SurpriseWindow, video_surprise
from voe_lightning.stats.verdicts import concept_verdicts, pair_groups

#: Keys of the dict that ``VRNNLRUModel.probe_step`` (and so ``test_step``) returns.
PROBE_OUTPUT_KEYS = (
    "concept",
    "variant",
    "seed",
    "manipulation_frame",
    "surprise_consistent",
    "surprise_inconsistent",
)
#: A key ``probe_step`` also returns, which a model's own probe step may leave out: the first
#: frame at which each pair's videos differ (``PairResults`` then takes manipulation_frame + 1).
FIRST_DIFFERENCE = "first_difference"
#: Columns of summary.csv, in order (``None`` cells mean "no test", explained in ``note``).
SUMMARY_COLUMNS = ("concept", "variant") + tuple(QuadrupletTestResult.__dataclass_fields__)


def as_numpy(values: Any, dtype: Any) -> np.ndarray:
    """A tensor (detached, on the CPU) or array-like as a numpy array of ``dtype``."""
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu().numpy()
    return np.asarray(values, dtype=dtype)


@dataclass(frozen=True, eq=False)
class PairResults:
    """Per-pair probe results of a run: names, seeds, manipulation frames, the first frame at
    which the pair's videos differ (None: manipulation_frame + 1) and per-frame surprise
    [N, T] of both videos. A video's surprise is the sum over its frames (§6)."""

    concept: tuple[str, ...]
    variant: tuple[str, ...]
    seed: np.ndarray
    manipulation_frame: np.ndarray
    surprise_consistent: np.ndarray
    surprise_inconsistent: np.ndarray
    first_difference: np.ndarray | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "concept", tuple(str(c) for c in self.concept))
        set_(self, "variant", tuple(str(v) for v in self.variant))
        if self.first_difference is None:
            set_(self, "first_difference", as_numpy(self.manipulation_frame, np.int64) + 1)
        for name, dtype in (
            ("seed", np.int64),
            ("manipulation_frame", np.int64),
            ("first_difference", np.int64),
            ("surprise_consistent", np.float64),
            ("surprise_inconsistent", np.float64),
        ):
            set_(self, name, as_numpy(getattr(self, name), dtype))
        n = len(self.concept)
        if self.surprise_consistent.ndim != 2 or self.surprise_consistent.shape[0] != n:
            raise ValueError(
                f"surprise_consistent must be [N={n}, T]; got {self.surprise_consistent.shape}"
            )
        shapes = {
            "variant": (len(self.variant),),
            "seed": self.seed.shape,
            "manipulation_frame": self.manipulation_frame.shape,
            "first_difference": self.first_difference.shape,
            "surprise_inconsistent": self.surprise_inconsistent.shape,
        }
        expected = {
            "variant": (n,),
            "seed": (n,),
            "manipulation_frame": (n,),
            "first_difference": (n,),
            "surprise_inconsistent": self.surprise_consistent.shape,
        }
        wrong = {k: v for k, v in shapes.items() if v != expected[k]}
        if wrong:
            raise ValueError(
                f"per-pair fields disagree with {n} pairs of "
                f"{self.num_frames} frames: {wrong} (expected {expected})"
            )

    @property
    def num_frames(self) -> int:
        return self.surprise_consistent.shape[1]

    def __len__(self) -> int:
        return len(self.concept)

    @property
    def total_consistent(self) -> np.ndarray:
        """Per-video surprise of the consistent videos: sum over frames, [N]."""
        return video_surprise(self.surprise_consistent)

    @property
    def total_inconsistent(self) -> np.ndarray:
        return video_surprise(self.surprise_inconsistent)

    @property
    def relative_surprise(self) -> np.ndarray:
        """Each pair's d = S(inconsistent) - S(consistent), [N]."""
        return self.total_inconsistent - self.total_consistent

    @property
    def causality(self) -> Causality:
        """Whether per-frame surprise is identical where each pair's videos are
        (``causality.check_prefix``): a report gives no verdict when it is not."""
        return check_prefix(
            self.surprise_consistent,
            self.surprise_inconsistent,
            self.manipulation_frame,
            self.first_difference,
        )

    def windowed(self, window: SurpriseWindow) -> PairResults:
        """These pairs with every frame outside ``window`` (counted from each pair's first
        difference) scoring 0, so each video's surprise is its sum over the window: the one
        place a window enters the statistics."""
        weights = window.frame_weights(self.num_frames, self.first_difference)
        return PairResults(
            self.concept,
            self.variant,
            self.seed,
            self.manipulation_frame,
            self.surprise_consistent * weights,
            self.surprise_inconsistent * weights,
            self.first_difference,
        )

    @classmethod
    def from_probe_outputs(
        cls,
        outputs: Sequence[Mapping[str, Any]],
        concept_names: Sequence[str] = CONCEPTS,
        variant_names: Sequence[str] = VARIANTS,
    ) -> PairResults:
        """From the dicts ``VRNNLRUModel.probe_step`` returns (one per batch), decoding the
        ``concept``/``variant`` indices with the DataModule's name tuples."""
        if not outputs:
            raise ValueError("no probe results: the list of probe_step outputs is empty")
        keys = PROBE_OUTPUT_KEYS
        if all(FIRST_DIFFERENCE in output for output in outputs):
            keys = (*keys, FIRST_DIFFERENCE)
        columns: dict[str, list[np.ndarray]] = {key: [] for key in keys}
        for index, output in enumerate(outputs):
            missing = [key for key in PROBE_OUTPUT_KEYS if key not in output]
            if missing:
                raise KeyError(
                    f"probe output {index} lacks {missing}; probe_step must return "
                    f"{list(PROBE_OUTPUT_KEYS)}"
                )
            for key in keys:
                columns[key].append(as_numpy(output[key], None))
        merged = {key: np.concatenate(values) for key, values in columns.items()}

        def decode(indices: np.ndarray, names: Sequence[str], what: str) -> tuple[str, ...]:
            bad = sorted({int(i) for i in indices if not 0 <= int(i) < len(names)})
            if bad:
                raise ValueError(
                    f"{what} indices {bad} are outside the {len(names)} {what} names {tuple(names)}"
                )
            return tuple(names[int(i)] for i in indices)

        return cls(
            concept=decode(merged["concept"], concept_names, "concept"),
            variant=decode(merged["variant"], variant_names, "variant"),
            seed=merged["seed"],
            manipulation_frame=merged["manipulation_frame"],
            surprise_consistent=merged["surprise_consistent"],
            surprise_inconsistent=merged["surprise_inconsistent"],
            first_difference=merged.get(FIRST_DIFFERENCE),
        )

    def select(self, rows: np.ndarray) -> PairResults:
        """The pairs at the given boolean mask or indices."""
        index = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
        return PairResults(
            concept=tuple(self.concept[i] for i in index),
            variant=tuple(self.variant[i] for i in index),
            seed=self.seed[index],
            manipulation_frame=self.manipulation_frame[index],
            surprise_consistent=self.surprise_consistent[index],
            surprise_inconsistent=self.surprise_inconsistent[index],
            first_difference=self.first_difference[index],
        )

    def groups(self, pooled: bool = False) -> list[tuple[str, str, PairResults]]:
        """(concept, variant, pairs) per concept/variant: concepts and variants in the order
        of ``specs`` where known, others after them in order of first appearance; with
        ``pooled``, also each concept's ``pooled`` group (standard + counterbalanced) and a
        group per quadruplet of ``specs.QUADRUPLETS`` (its first halves, then its second halves,
        matched by seed; ``verdicts.pair_groups``)."""
        return [
            (concept, variant, self.select(rows))
            for concept, variant, rows in pair_groups(
                self.concept, self.variant, pooled=pooled, seeds=self.seed
            )
        ]

    def csv_columns(self) -> list[str]:
        frames = [f"t{t:02d}" for t in range(self.num_frames)]
        return (
            [
                "concept",
                "variant",
                "seed",
                "manipulation_frame",
                "surprise_consistent",
                "surprise_inconsistent",
                "relative_surprise",
                FIRST_DIFFERENCE,
            ]
            + [f"surprise_consistent_{f}" for f in frames]
            + [f"surprise_inconsistent_{f}" for f in frames]
        )

    def to_csv(self, path: str | Path) -> None:
        """pairs.csv: one row per pair; floats written with full precision (repr)."""
        with open(path, "w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(self.csv_columns())
            totals = zip(self.total_consistent, self.total_inconsistent)
            for i, (con, inc) in enumerate(totals):
                writer.writerow(
                    [
                        self.concept[i],
                        self.variant[i],
                        int(self.seed[i]),
                        int(self.manipulation_frame[i]),
                        repr(float(con)),
                        repr(float(inc)),
                        repr(float(inc - con)),
                        int(self.first_difference[i]),
                    ]
                    + [repr(float(x)) for x in self.surprise_consistent[i]]
                    + [repr(float(x)) for x in self.surprise_inconsistent[i]]
                )

    @classmethod
    def from_csv(cls, path: str | Path) -> PairResults:
        """Read pairs.csv back (per-frame surprise columns define the results), checked: every
        row whole and numeric, its totals the sums of its frames and, where summary.json lies
        beside it, as many rows as it counts pairs and the SHA-256 it recorded (which catches
        a last value cut short). A file that fails is named as corrupt."""
        path = Path(path)
        with open(path, newline="") as handle:
            rows = list(csv.DictReader(handle))
        if not rows:
            raise ValueError(f"{path} holds no probe pairs")
        columns = list(rows[0])
        con_cols = [c for c in columns if c.startswith("surprise_consistent_t")]
        inc_cols = [c for c in columns if c.startswith("surprise_inconsistent_t")]
        if not con_cols or len(con_cols) != len(inc_cols):
            raise ValueError(
                f"{path} lacks per-frame surprise columns "
                "surprise_consistent_tNN / surprise_inconsistent_tNN"
            )
        for line, row in enumerate(rows, start=2):
            _check_pair_row(path, line, row, con_cols, inc_cols)
        if path.with_name("summary.json").is_file():
            _check_against_summary(path, len(rows))
        return cls(
            concept=[r["concept"] for r in rows],
            variant=[r["variant"] for r in rows],
            seed=[int(r["seed"]) for r in rows],
            manipulation_frame=[int(r["manipulation_frame"]) for r in rows],
            surprise_consistent=[[float(r[c]) for c in con_cols] for r in rows],
            surprise_inconsistent=[[float(r[c]) for c in inc_cols] for r in rows],
            first_difference=(
                [int(r[FIRST_DIFFERENCE]) for r in rows] if FIRST_DIFFERENCE in columns else None
            ),
        )


def _check_pair_row(
    path: Path,
    line: int,
    row: Mapping[str, str | None],
    con_cols: Sequence[str],
    inc_cols: Sequence[str],
) -> None:
    """Refuse, naming ``path`` and ``line``, a pairs.csv row with a missing or non-numeric
    value or whose totals are not the sums of its per-frame surprise."""
    corrupt = f"{path} is corrupt (truncated?) at line {line}"
    if None in row:
        raise ValueError(f"{corrupt}: more values than columns")
    missing = [name for name, value in row.items() if value in (None, "")]
    if missing:
        raise ValueError(f"{corrupt}: no value for {', '.join(missing)}")
    numbers = {}
    optional = [FIRST_DIFFERENCE] if FIRST_DIFFERENCE in row else []
    for name in (
        "seed",
        "manipulation_frame",
        *optional,
        "surprise_consistent",
        "surprise_inconsistent",
        *con_cols,
        *inc_cols,
    ):
        try:
            numbers[name] = float(row[name])
        except ValueError:
            raise ValueError(f"{corrupt}: {name} is {row[name]!r}, not a number") from None
    for total, frames in (("surprise_consistent", con_cols), ("surprise_inconsistent", inc_cols)):
        summed = math.fsum(numbers[name] for name in frames)
        if not math.isclose(summed, numbers[total], rel_tol=1e-9, abs_tol=1e-9):
            raise ValueError(f"{corrupt}: {total} is {row[total]}, its frames sum to {summed!r}")


def _check_against_summary(path: Path, num_rows: int) -> None:
    """Refuse a pairs.csv whose row count or SHA-256 differs from what the summary.json
    beside it recorded when both were written."""
    summary = read_summary(path.parent)
    corrupt = f"{path} is corrupt (truncated?)"
    rewrite = "run test again to rewrite it"
    if summary.get("num_pairs") is not None and summary["num_pairs"] != num_rows:
        raise ValueError(
            f"{corrupt}: it holds {num_rows} pairs, {path.with_name('summary.json')} "
            f"counts {summary['num_pairs']}; {rewrite}"
        )
    recorded = summary.get("pairs_csv_sha256")
    if recorded is not None and recorded != _sha256(path):
        raise ValueError(
            f"{corrupt}: its SHA-256 is not the one "
            f"{path.with_name('summary.json')} recorded; {rewrite}"
        )


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def read_summary(report_dir: str | Path) -> dict[str, Any]:
    """A report's summary.json, naming the file when it is truncated or not a summary."""
    path = Path(report_dir) / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except ValueError as error:
        raise ValueError(
            f"{path} is corrupt (truncated?): {error}; run test again to rewrite it"
        ) from None
    if not isinstance(summary, dict) or not isinstance(summary.get("rows"), list):
        raise ValueError(f"{path} is not a voe_report summary (no rows); run test again")
    return summary


def summarize(
    results: PairResults, alpha: float = ALPHA, bootstrap: int = 2000, seed: int = 0
) -> list[dict[str, Any]]:
    """One row per concept/variant, a ``pooled`` row per concept with a counterbalanced
    pair (``statistics.pooled_test``: the stratified test of its variants' mean differences)
    and a row per quadruplet of ``specs.QUADRUPLETS`` (``statistics.quadruplet_test``): the test
    of summed surprise (``statistics.group_test``). A group without a test (fewer than two
    pairs, ``statistics.untested_reason``) gets ``None`` statistics and a note instead of
    failing the report; columns a row's test lacks (the halves of a pair test) are ``None``."""
    rows = []
    for concept, variant, pairs in results.groups(pooled=True):
        row: dict[str, Any] = dict.fromkeys(SUMMARY_COLUMNS)
        row.update(concept=concept, variant=variant)
        reason = untested_reason(variant, pairs.variant)
        if reason:
            row.update(n=len(pairs) // (2 if variant in QUADRUPLET_ROWS else 1), note=reason)
        else:
            row.update(
                group_test(
                    variant,
                    pairs.total_inconsistent,
                    pairs.total_consistent,
                    pairs.variant,
                    alpha=alpha,
                    bootstrap=bootstrap,
                    seed=seed,
                ).as_dict()
            )
        rows.append(row)
    return rows


def field_metric_rows(results: PairResults) -> dict[str, dict[str, Any]]:
    """The field's metric set (``field_metrics.field_metrics``: relative accuracy with sum,
    mean and max surprise, absolute accuracy, AUROC) per concept/variant and pooled group, keyed
    ``<concept>/<variant>``; each group's threshold is from its own consistent videos, as
    surprise scales differ between concepts. A group with non-finite surprise gets a note."""
    rows = {}
    for concept, variant, pairs in results.groups(pooled=True):
        sides = (pairs.surprise_consistent, pairs.surprise_inconsistent)
        rows[f"{concept}/{variant}"] = (
            field_metrics(*sides)
            if all(np.isfinite(side).all() for side in sides)
            else {"n_pairs": len(pairs), "note": "surprise is not finite: no metrics"}
        )
    return rows


def format_verdicts(
    rows: Sequence[Mapping[str, Any]], causality: Causality | None = None
) -> list[str]:
    """Markdown lines of the ``causality`` check and each concept's VOE verdict
    (``verdicts.concept_verdicts``, withheld when the check failed)."""
    lines = [causality.line(), ""] if causality is not None else []
    for verdict in concept_verdicts(rows, rows_alpha(rows), causality):
        text = "**VOE**" if verdict.voe else verdict.text()
        lines.append(f"- {verdict.concept}: {text} (rule: {verdict.rule})")
    return lines


#: What a frame's surprise is unless told otherwise: the paper's (the VRNN-LRU's).
VRNN_SURPRISE = VRNNLRUModel.SURPRISE


def format_markdown(
    rows: Sequence[Mapping[str, Any]],
    surprise: str = VRNN_SURPRISE,
    window: SurpriseWindow = SurpriseWindow(),
    causality: Causality | None = None,
) -> str:
    """The summary as a Markdown table (paper notation, alpha in its header), notes as
    footnotes below it, then the ``causality`` check and each concept's VOE verdict;
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
    lines += format_verdicts(rows, causality)
    return "\n".join(lines) + "\n"


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


def write_summary(
    results: PairResults,
    rows: Sequence[Mapping[str, Any]],
    report_dir: Path,
    *,
    alpha: float,
    bootstrap: int,
    surprise: str,
    source: Mapping[str, Any] | None = None,
    window: SurpriseWindow = SurpriseWindow(),
    window_rows: Sequence[Mapping[str, Any]] | None = None,
    priors_alone: Mapping[str, Any] | None = None,
) -> str:
    """Write pairs.csv, summary.json (with ``source``: what the report was made from, and
    pairs.csv's SHA-256, which ``PairResults.from_csv`` checks), summary.csv and summary.md
    (of ``summarize``'s ``rows``, over all frames, and the field's metrics of
    ``field_metric_rows``) into ``report_dir``; with a ``window``
    other than all frames, its ``window_rows`` go beside them: summary.json's ``window``,
    summary_window.csv and a section of summary.md; ``priors_alone`` (the untrained copy's
    summary, ``null.priors_alone``) gives summary.json's ``priors_alone`` and its section of
    summary.md. Return the Markdown summary."""
    results.to_csv(report_dir / "pairs.csv")
    causality = results.causality
    document = {
        "source": dict(source or {}),
        "alpha": alpha,
        "bootstrap_resamples": bootstrap,
        "num_pairs": len(results),
        "pairs_csv_sha256": _sha256(report_dir / "pairs.csv"),
        "num_frames": results.num_frames,
        "video_surprise": f"sum over frames of {surprise}",
        "surprise_window": window.as_config(),
        "causality": causality.as_dict(),
        **_tables(rows, alpha, causality),
        "field_metrics": field_metric_rows(results),
    }
    with open(report_dir / "summary.csv", "w", newline="") as handle:
        _write_rows(handle, rows)
    markdown = format_source(document["source"]) + format_markdown(
        rows, surprise, causality=causality
    )
    if priors_alone is not None:
        document["priors_alone"] = priors_alone_document(priors_alone)
        markdown += "\n" + format_priors_alone(
            document["rows"], document["verdicts"], document["priors_alone"]
        )
    if not window.all_frames:
        document["window"] = {
            "surprise_window": window.as_config(),
            "video_surprise": f"sum over the {window.describe()} of {surprise}",
            **_tables(window_rows, alpha, causality),
        }
        with open(report_dir / "summary_window.csv", "w", newline="") as handle:
            _write_rows(handle, window_rows)
        markdown += (
            f"\n## Surprise window: {window.describe()}\n\nBeside the paper's sums "
            "over all frames above, never instead of them.\n\n"
            + format_markdown(window_rows, surprise, window, causality)
        )
    else:
        markdown += "\nSurprise window: all frames (the paper's).\n"
    markdown += "\n## The field's metrics (all frames)\n\n" + format_field_metrics(
        document["field_metrics"], "concept/variant"
    )
    (report_dir / "summary.json").write_text(json.dumps(document, indent=2) + "\n")
    (report_dir / "summary.md").write_text(markdown)
    return markdown


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
        parts.append(
            f"the probes of {where}" + (f" (seed offset {offset})" if offset is not None else "")
        )
    return f"Tested: {'; '.join(parts)}.\n\n" if parts else ""


def _tables(
    rows: Sequence[Mapping[str, Any]], alpha: float, causality: Causality
) -> dict[str, Any]:
    """summary.json's ``rows`` (strict JSON) and ``verdicts`` of ``summarize``'s rows (none
    given where ``causality`` failed)."""
    return {
        "rows": [json_row(row) for row in rows],
        "verdicts": [
            {"concept": v.concept, "voe": v.voe, "verdict": v.text(), "rule": v.rule}
            for v in concept_verdicts(rows, alpha, causality)
        ],
    }


def _write_rows(handle: Any, rows: Sequence[Mapping[str, Any]]) -> None:
    """``summarize``'s rows as CSV (``SUMMARY_COLUMNS``)."""
    writer = csv.DictWriter(handle, fieldnames=SUMMARY_COLUMNS)
    writer.writeheader()
    writer.writerows(rows)
