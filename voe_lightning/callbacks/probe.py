"""``VOEProbeCallback``: VOE statistics of the validation probes over training, and the
console table of them (``voe_table``) that ``fit`` prints at its end."""

from __future__ import annotations

import functools
from collections import defaultdict
from collections.abc import Mapping
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.trainer.states import TrainerFn
from lightning.pytorch.utilities import rank_zero_warn
from rich import box
from rich.console import Console, Group
from rich.table import Table
from rich.text import Text

from voe_lightning.callbacks.common import (
    ProbeOutcome,
    RunAlpha,
    check_finite_surprise,
    gather_objects,
    probe_names,
)
from voe_lightning.probe_datamodule import probe_datamodule
from voe_lightning.stats.causality import Causality, check_prefix
from voe_lightning.stats.statistics import (
    POOLED,
    POOLED_VARIANTS,
    quadruplet_test,
)
from voe_lightning.stats.statistics_format import CONSOLE, format_alpha, row_text
from voe_lightning.stats.streaming_statistics import (
    PairedSurpriseStats,
    TooFewPairs,
    pooled_values,
)
from voe_lightning.stats.surprise_window import SurpriseWindow, video_surprise
from voe_lightning.stats.t_tests import FLOAT32_ROUNDING, rounding_of
from voe_lightning.stats.verdicts import concept_verdicts, pair_groups, quadruplets

#: A quadruplet row's means of its halves, logged beside its statistics.
HALVES = ("first_half", "second_half")


class VOEProbeCallback(RunAlpha, L.Callback):
    """Every validation run (set its frequency with ``trainer.val_check_interval``, in training
    steps) streams each probe pair's relative surprise into one PairedSurpriseStats per
    concept/variant, then logs ``voe/<concept>/<variant>/{relative_surprise,t,p_value,accuracy,n}``.
    A concept with a standard and a counterbalanced variant also gets
    ``voe/<concept>/pooled/...``: the stratified test of its two variants
    (``streaming_statistics.pooled_values``, from their float64 sums, so exact under DDP as
    they are); and each quadruplet the validation probes hold (matched by seed,
    ``verdicts.quadruplets``), ``voe/<concept>/<quadruplet row>/...`` with its halves' means
    (``first_half``, ``second_half``): the quadruplet test the verdict reads, as the report's.
    At the end of ``fit`` (and of ``validate``) it prints the last table with each concept's
    verdict at ``alpha``, the run's significance level (the CLI gives the run's ``alpha``,
    configs/base.yaml).
    A ``surprise_window`` other than all frames (``surprise_window.surprise_window``; the CLI
    gives the run's) logs the same statistics of each video's surprise summed over that window
    beside them, as ``voe_window/...``. Each validation run also checks causality
    (``stats.causality.check_prefix``): ``causality`` holds the last run's finding; where surprise
    differs through the pairs' manipulation frame it warns, and the table gives no verdict."""

    STATISTICS = ("relative_surprise", "t", "p_value", "accuracy", "n")

    def __init__(
        self,
        print_table: bool = True,
        alpha: float | None = None,
        surprise_window: SurpriseWindow | None = None,
    ):
        super().__init__(alpha)
        self.print_table = print_table
        window = surprise_window or SurpriseWindow()
        #: The windows whose statistics are logged, by log prefix: all frames first.
        self.windows = {
            "voe": SurpriseWindow(),
            **({} if window.all_frames else {"voe_window": window}),
        }
        self.metrics: dict[tuple[str, str, str], PairedSurpriseStats] = {}
        self.last: dict[tuple[str, str], dict[str, float]] = {}
        #: The training step the ``last`` statistics were measured at (what the table names).
        self.last_step = 0
        self.causality: Causality | None = None
        self._causality = Causality()
        #: Per log prefix, this validation run's pairs (concept, variant, seed, S(inc), S(con)),
        #: which the quadruplet rows match by seed.
        self._pairs: dict[str, list[tuple[str, str, int, float, float]]] = {}
        #: The rounding of this validation run's per-frame surprise (``t_tests.rounding_of``),
        #: within which a d is 0, as in the report.
        self._rounding = FLOAT32_ROUNDING

    @property
    def outcome(self) -> ProbeOutcome:
        """The last validation's causality check; no report."""
        return ProbeOutcome(self.causality)

    def on_validation_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        cases = probe_datamodule(trainer, type(self).__name__).probe_cases("val")
        # Create every metric up front so all DDP ranks hold the same states.
        for prefix in self.windows:
            for case in cases:
                self._metric((prefix, *case), pl_module.device)
        for metric in self.metrics.values():
            metric.reset()
        self._causality = Causality()
        self._pairs = {prefix: [] for prefix in self.windows}
        self._rounding = FLOAT32_ROUNDING

    def _metric(self, key: tuple[str, str, str], device: torch.device) -> PairedSurpriseStats:
        if key not in self.metrics:
            self.metrics[key] = PairedSurpriseStats().to(device)
        return self.metrics[key]

    def on_validation_batch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
        dataloader_idx: int = 0,
    ) -> None:
        if not outputs:
            return
        concept_names, variant_names = probe_names(trainer, type(self).__name__)
        check_finite_surprise(outputs, concept_names, variant_names)
        self._causality = self._causality.merge(
            check_prefix(
                outputs["surprise_consistent"],
                outputs["surprise_inconsistent"],
                outputs["manipulation_frame"],
                outputs.get("inputs_differ", outputs.get("first_difference")),
            )
        )
        names = [
            (concept_names[c], variant_names[v])
            for c, v in zip(outputs["concept"].tolist(), outputs["variant"].tolist())
        ]
        groups: defaultdict[tuple[str, str], list[int]] = defaultdict(list)
        for index, case in enumerate(names):
            groups[case].append(index)
        seeds = outputs["seed"].tolist() if "seed" in outputs else None
        rounding = rounding_of(outputs["surprise_consistent"], outputs["surprise_inconsistent"])
        self._rounding = min(self._rounding, rounding)
        for prefix, window in self.windows.items():
            inconsistent, consistent = (
                _window_sum(outputs, side, window) for side in ("inconsistent", "consistent")
            )
            if seeds is not None:  # probes without seeds have no quadruplets to match
                self._pairs.setdefault(prefix, []).extend(
                    (concept, variant, seed, inc, con)
                    for (concept, variant), seed, inc, con in zip(
                        names, seeds, inconsistent.double().tolist(), consistent.double().tolist()
                    )
                )
            for case, indices in groups.items():
                rows = torch.tensor(indices, device=inconsistent.device)
                self._metric((prefix, *case), pl_module.device).update(
                    inconsistent[rows], consistent[rows], rounding
                )

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        # Every rank's pairs (under DDP each rank scored its own), as the statistics are.
        self.causality = functools.reduce(Causality.merge, gather_objects(self._causality))
        if not self.causality.causal:
            rank_zero_warn(f"validation at step {trainer.global_step}: {self.causality.line()}")
        for prefix in self.windows:
            results = self._with_quadruplets(self._results(prefix), prefix)
            for (concept, variant), values in results.items():
                for statistic in self.STATISTICS + HALVES:
                    if statistic not in values:
                        continue
                    pl_module.log(
                        f"{prefix}/{concept}/{variant}/{statistic}",
                        values[statistic],
                        sync_dist=False,
                    )
            if prefix == "voe":
                self.last, self.last_step = results, trainer.global_step

    def _results(self, prefix: str) -> dict[tuple[str, str], dict[str, float]]:
        """The statistics of the window logged under ``prefix``, per concept/variant with the
        pooled rows, of the cases with at least two pairs so far."""
        computed = {}
        for (window, *case), metric in self.metrics.items():
            if window != prefix:
                continue
            try:  # called on every rank alike: compute() syncs the states under DDP
                computed[tuple(case)] = {k: float(v) for k, v in metric.compute().items()}
            except TooFewPairs:  # fewer than two pairs of this case so far
                continue
        results = {}
        concepts, variants = zip(*computed) if computed else ((), ())
        for concept, variant, _ in pair_groups(concepts, variants):
            if variant == POOLED:
                results[(concept, variant)] = pooled_values(
                    [computed[(concept, v)] for v in POOLED_VARIANTS]
                )
            else:
                results[(concept, variant)] = computed[(concept, variant)]
        return results

    def _with_quadruplets(
        self, results: dict[tuple[str, str], dict[str, float]], prefix: str
    ) -> dict[tuple[str, str], dict[str, float]]:
        """``results`` with each concept's quadruplet rows (every rank's pairs matched by seed,
        ``quadruplet_test``; two quadruplets at least) after its own rows."""
        pairs = [pair for rank in gather_objects(self._pairs.get(prefix, [])) for pair in rank]
        if not pairs:
            return results
        concepts, variants, seeds, inconsistent, consistent = (np.array(x) for x in zip(*pairs))
        rows: dict[str, list[tuple[str, dict[str, float]]]] = defaultdict(list)
        for concept, row, first, second in quadruplets(concepts, variants, seeds):
            if first.size < 2:
                continue
            test = quadruplet_test(
                inconsistent[first],
                consistent[first],
                inconsistent[second],
                consistent[second],
                self.alpha,
                bootstrap=0,
                rounding=self._rounding,
            )
            values = {k: test.as_dict()[k] for k in self.STATISTICS + HALVES}
            rows[concept].append((row, {k: float(v) for k, v in values.items()}))
        ordered = {}
        for concept in dict.fromkeys(concept for concept, _ in results):
            ordered.update({key: value for key, value in results.items() if key[0] == concept})
            ordered.update({(concept, row): values for row, values in rows.get(concept, [])})
        return ordered

    def on_fit_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._print_last(trainer)

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.state.fn == TrainerFn.VALIDATING:  # ``validate`` alone; fit's prints at its end
            self._print_last(trainer)

    def _print_last(self, trainer: L.Trainer) -> None:
        """Print the last validation's table, each concept's verdict on its heading row."""
        if self.print_table and self.last and trainer.is_global_zero:
            console = Console()
            if not console.is_terminal:  # logs and pipes: do not cut the table at 80 columns
                console.width = 120
            # the last validation's step: fit may end after it (a cadence in epochs)
            title = f"VOE on validation probes, step {self.last_step}"
            console.print(
                voe_table(self.last, title=title, alpha=self.alpha, causality=self.causality)
            )


def _window_sum(outputs: Mapping[str, Any], side: str, window: SurpriseWindow) -> torch.Tensor:
    """Each ``side`` video's surprise of probe ``outputs`` over ``window`` from its pair's first
    difference (``manipulation_frame`` + 1 where the outputs lack it), [B]."""
    first = (
        None
        if window.all_frames
        else outputs["first_difference"]
        if "first_difference" in outputs
        else outputs["manipulation_frame"] + 1
    )
    summed: torch.Tensor = video_surprise(outputs[f"surprise_{side}"], window, first)
    return summed


#: Footnote marks of the verdicts that say why (``voe_table``), then numbers.
MARKS = "¹²³⁴⁵⁶⁷⁸⁹"


def voe_table(
    results: dict[tuple[str, str], dict[str, float]],
    title: str,
    alpha: float,
    causality: Causality | None = None,
) -> Group:
    """A table of relative surprise M, t, p and accuracy per concept (a heading row) and
    variant (pooled rows bold: the stratified test), alpha in its title, that fits an
    80-column terminal: each concept's verdict (``verdicts.concept_verdicts``, withheld where
    ``causality`` failed, whose line is the caption) on its heading row, and why a concept
    shows none in a footnote under the table rather than in a cell that would wrap."""
    verdicts = {v.concept: v for v in concept_verdicts(results, alpha, causality)}
    caption = f"* p < {alpha:g}, one-tailed paired t-test"
    if causality is not None:
        caption += "\n" + causality.line()
    table = Table(
        title=f"{title} ({format_alpha(alpha)})",
        caption=caption,
        box=box.SIMPLE_HEAD,
        pad_edge=False,
        collapse_padding=True,
    )
    for column in ("concept / variant", "n", "M", "t", "p", "acc", "verdict"):
        table.add_column(column, justify="left" if "/" in column else "right", no_wrap=True)
    notes: list[str] = []
    for concept in dict.fromkeys(concept for concept, _ in results):
        verdict = verdicts[concept]
        text = "VOE"
        if not verdict.voe:  # "no VOE", "undecided" or "no verdict", and why in a footnote
            mark = MARKS[len(notes)] if len(notes) < len(MARKS) else f"({len(notes) + 1})"
            text = verdict.text().split(":")[0] + mark
            notes.append(f"{mark} {concept}: {verdict.text()}")
        colour = "green" if verdict.voe else "red" if verdict.voe is False else "yellow"
        table.add_row(f"[bold]{concept}[/bold]", *[""] * 5, f"[{colour}]{text}[/{colour}]")
        rows = [(variant, values) for (name, variant), values in results.items() if name == concept]
        for index, (variant, values) in enumerate(rows):
            cells = row_text(values, CONSOLE, alpha)
            table.add_row(
                f"  {variant}",
                cells.n,
                cells.mean,
                cells.t,
                cells.p + cells.star,
                cells.accuracy,
                "",
                style="bold" if variant == POOLED else None,
                end_section=index + 1 == len(rows),
            )
    return Group(table, *(Text(note) for note in notes))
