"""A run's per-pair probe results (``PairResults``): built from the model's probe outputs,
grouped per concept/variant, pooled group and quadruplet, windowed, and written to / read back
(checked) from pairs.csv."""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch

from voe_lightning.report.summary_file import file_sha256, read_summary
from voe_lightning.specs import CONCEPTS, VARIANTS
from voe_lightning.stats.causality import Causality, check_prefix
from voe_lightning.stats.surprise_window import SurpriseWindow, video_surprise
from voe_lightning.stats.verdicts import pair_groups

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
#: Key of ``probe_step``'s first frame at which a pair's inputs (frames, masks, states) differ.
INPUTS_DIFFER = "inputs_differ"


def as_numpy(values: Any, dtype: Any) -> np.ndarray:
    """A tensor (detached, on the CPU; bf16/fp16 widened to float32, which numpy lacks) or
    array-like as a numpy array of ``dtype``, always a copy of its own: a model's output may
    be a view of a buffer it overwrites with the next batch's."""
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu()
        if values.is_floating_point() and values.element_size() < 4:
            values = values.float()
        values = values.numpy()
    return np.array(values, dtype=dtype)


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
    inputs_differ: np.ndarray | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "concept", tuple(str(c) for c in self.concept))
        set_(self, "variant", tuple(str(v) for v in self.variant))
        if self.first_difference is None:
            set_(self, "first_difference", as_numpy(self.manipulation_frame, np.int64) + 1)
        if self.inputs_differ is None:
            set_(self, "inputs_differ", self.first_difference)
        for name, dtype in (
            ("seed", np.int64),
            ("manipulation_frame", np.int64),
            ("first_difference", np.int64),
            ("inputs_differ", np.int64),
            ("surprise_consistent", np.float64),
            ("surprise_inconsistent", np.float64),
        ):
            set_(self, name, as_numpy(getattr(self, name), dtype))
        assert self.first_difference is not None and self.inputs_differ is not None  # set above
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
            "inputs_differ": self.inputs_differ.shape,
            "surprise_inconsistent": self.surprise_inconsistent.shape,
        }
        expected = {
            "variant": (n,),
            "seed": (n,),
            "manipulation_frame": (n,),
            "first_difference": (n,),
            "inputs_differ": (n,),
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
        return int(self.surprise_consistent.shape[1])

    def __len__(self) -> int:
        return len(self.concept)

    @property
    def total_consistent(self) -> np.ndarray:
        """Per-video surprise of the consistent videos: sum over frames, [N]."""
        return cast(np.ndarray, video_surprise(self.surprise_consistent))

    @property
    def total_inconsistent(self) -> np.ndarray:
        return cast(np.ndarray, video_surprise(self.surprise_inconsistent))

    @property
    def relative_surprise(self) -> np.ndarray:
        """Each pair's d = S(inconsistent) - S(consistent), [N]."""
        d: np.ndarray = self.total_inconsistent - self.total_consistent
        return d

    @property
    def causality(self) -> Causality:
        """Whether per-frame surprise is identical before each pair's inputs differ
        (``stats.causality.check_prefix``): a report gives no verdict when it is not. Read
        back from pairs.csv, which keeps only the frames' first difference, that is the bound."""
        return check_prefix(
            self.surprise_consistent,
            self.surprise_inconsistent,
            self.manipulation_frame,
            self.inputs_differ,
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
            self.inputs_differ,
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
        keys: tuple[str, ...] = PROBE_OUTPUT_KEYS
        for optional in (FIRST_DIFFERENCE, INPUTS_DIFFER):
            if all(optional in output for output in outputs):
                keys = (*keys, optional)
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
            inputs_differ=merged.get(INPUTS_DIFFER),
        )

    def select(self, rows: np.ndarray) -> PairResults:
        """The pairs at the given boolean mask or indices."""
        index = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
        assert self.first_difference is not None and self.inputs_differ is not None  # __post_init__
        return PairResults(
            concept=tuple(self.concept[i] for i in index),
            variant=tuple(self.variant[i] for i in index),
            seed=self.seed[index],
            manipulation_frame=self.manipulation_frame[index],
            surprise_consistent=self.surprise_consistent[index],
            surprise_inconsistent=self.surprise_inconsistent[index],
            first_difference=self.first_difference[index],
            inputs_differ=self.inputs_differ[index],
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
            assert self.first_difference is not None  # set in __post_init__
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
            concept=tuple(r["concept"] for r in rows),
            variant=tuple(r["variant"] for r in rows),
            seed=np.array([int(r["seed"]) for r in rows]),
            manipulation_frame=np.array([int(r["manipulation_frame"]) for r in rows]),
            surprise_consistent=np.array([[float(r[c]) for c in con_cols] for r in rows]),
            surprise_inconsistent=np.array([[float(r[c]) for c in inc_cols] for r in rows]),
            first_difference=(
                np.array([int(r[FIRST_DIFFERENCE]) for r in rows])
                if FIRST_DIFFERENCE in columns
                else None
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
            numbers[name] = float(cast(str, row[name]))  # None refused above as missing
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
    if recorded is not None and recorded != file_sha256(path):
        raise ValueError(
            f"{corrupt}: its SHA-256 is not the one "
            f"{path.with_name('summary.json')} recorded; {rewrite}"
        )
