"""Training-time callbacks, one concern each: VOE statistics of the validation probes over
training, and image strips of what the model expected to see."""

from __future__ import annotations

from collections import defaultdict

import lightning as L
import torch
from rich.console import Console
from rich.table import Table

from voe_lightning import specs
from voe_lightning.model.base import video_inputs
from voe_lightning.statistics import (
    POOLED,
    POOLED_VARIANTS,
    PairedSurpriseStats,
    concept_verdicts,
    pair_groups,
)


def _names(trainer: L.Trainer) -> tuple[tuple[str, ...], tuple[str, ...]]:
    datamodule = trainer.datamodule
    return (
        getattr(datamodule, "concept_names", specs.CONCEPTS),
        getattr(datamodule, "variant_names", specs.VARIANTS),
    )


class VOEProbeCallback(L.Callback):
    """Every validation run (set its frequency with ``trainer.val_check_interval``, in training
    steps) streams each probe pair's relative surprise into one PairedSurpriseStats per
    concept/variant, then logs ``voe/<concept>/<variant>/{relative_surprise,t,p_value,accuracy}``.
    A concept with a standard and a counterbalanced variant also streams every one of their
    pairs into a third metric, logged as ``voe/<concept>/pooled/...``: the test over the union
    of both variants' pairs. The sums are float64 torchmetrics states, so the result is exact
    under DDP. At the end of ``fit`` it prints the last table with each concept's verdict."""

    STATISTICS = ("relative_surprise", "t", "p_value", "accuracy")

    def __init__(self, print_table: bool = True, alpha: float = 0.05):
        super().__init__()
        if not 0.0 < alpha < 1.0:
            raise ValueError(f"alpha must be in (0, 1), got {alpha}")
        self.print_table = print_table
        self.alpha = alpha
        self.metrics: dict[tuple[str, str], PairedSurpriseStats] = {}
        self.last: dict[tuple[str, str], dict[str, float]] = {}

    def on_validation_epoch_start(self, trainer, pl_module) -> None:
        cases = getattr(trainer.datamodule, "probe_cases", lambda split="val": [])("val")
        concepts, variants = zip(*cases) if cases else ((), ())
        pooled = [(c, v) for c, v, _ in pair_groups(concepts, variants) if v == POOLED]
        # Create every metric up front so all DDP ranks hold the same states.
        for case in list(cases) + pooled:
            self._metric(case, pl_module.device)
        for metric in self.metrics.values():
            metric.reset()

    def _metric(self, case: tuple[str, str], device: torch.device) -> PairedSurpriseStats:
        if case not in self.metrics:
            self.metrics[case] = PairedSurpriseStats().to(device)
        return self.metrics[case]

    def on_validation_batch_end(
        self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0
    ) -> None:
        if not outputs:
            return
        concept_names, variant_names = _names(trainer)
        inconsistent = outputs["surprise_inconsistent"].sum(-1)
        consistent = outputs["surprise_consistent"].sum(-1)
        groups = defaultdict(list)
        for index, (c, v) in enumerate(zip(outputs["concept"].tolist(), outputs["variant"].tolist())):
            groups[(concept_names[c], variant_names[v])].append(index)
        for (concept, variant), rows in groups.items():
            rows = torch.tensor(rows, device=inconsistent.device)
            cases = [(concept, variant)]
            if variant in POOLED_VARIANTS:
                cases.append((concept, POOLED))  # the union: its states sum both variants'
            for case in cases:
                self._metric(case, pl_module.device).update(inconsistent[rows], consistent[rows])

    def on_validation_epoch_end(self, trainer, pl_module) -> None:
        if trainer.sanity_checking:
            return
        self.last = {}
        concepts, variants = zip(*self.metrics) if self.metrics else ((), ())
        order = [(c, v) for c, v, _ in pair_groups(concepts, variants, pooled=False)]
        for concept, variant in order:
            metric = self.metrics[(concept, variant)]
            if variant == POOLED and not all((concept, v) in self.metrics for v in POOLED_VARIANTS):
                continue  # one variant alone: nothing to pool
            try:  # called on every rank alike: compute() syncs the states under DDP
                values = {k: float(v) for k, v in metric.compute().items()}
            except ValueError:  # fewer than two pairs of this case so far
                continue
            self.last[(concept, variant)] = values
            for statistic in self.STATISTICS:
                pl_module.log(
                    f"voe/{concept}/{variant}/{statistic}", values[statistic], sync_dist=False
                )

    def on_fit_end(self, trainer, pl_module) -> None:
        if self.print_table and self.last and trainer.is_global_zero:
            console = Console()
            if not console.is_terminal:  # logs and pipes: do not cut the table at 80 columns
                console.width = 120
            title = f"VOE on validation probes, step {trainer.global_step}"
            console.print(voe_table(self.last, title=title, alpha=self.alpha))


def voe_table(
    results: dict[tuple[str, str], dict[str, float]], title: str, alpha: float = 0.05
) -> Table:
    """A rich table of relative surprise, t, p and accuracy per concept/variant (pooled rows
    bold), with each concept's verdict (``statistics.concept_verdicts``) on its first row."""
    verdicts = {v.concept: v for v in concept_verdicts(results, alpha)}
    table = Table(title=title)
    for column in ("concept", "variant", "n", "relative surprise", "t", "p (one-tailed)",
                   "accuracy", "verdict"):
        justify = "left" if column in ("concept", "variant", "verdict") else "right"
        table.add_column(column, justify=justify, overflow="fold")
    keys = list(results)
    for index, ((concept, variant), values) in enumerate(results.items()):
        marker = "*" if values["p_value"] < alpha else ""
        first = index == 0 or keys[index - 1][0] != concept
        last = index + 1 == len(keys) or keys[index + 1][0] != concept
        verdict = verdicts[concept]
        text = verdict.text() if first else ""
        if first and verdict.voe is not None:
            text = f"[green]{text}[/green]" if verdict.voe else f"[red]{text}[/red]"
        table.add_row(
            concept if first else "",
            variant,
            f"{values['n']:.0f}",
            f"{values['relative_surprise']:.3f}",
            f"{values['t']:.2f}",
            f"{values['p_value']:.3g}{marker}",
            f"{values['accuracy']:.2f}",
            text,
            style="bold" if variant == POOLED else None,
            end_section=last,
        )
    return table


class ExpectationImages(L.Callback):
    """At each validation run, logs to TensorBoard, for one fixed inconsistent validation probe
    per concept, the input frames above ``expected_frames`` (given the probe's mask and camera):
    what the model expected to see given the previous frames (the paper's Figure 5)."""

    def __init__(self, max_frames: int = 15):
        super().__init__()
        self.max_frames = max_frames
        self.examples: dict[str, torch.Tensor] = {}

    def on_validation_batch_end(
        self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0
    ) -> None:
        concept_names, _ = _names(trainer)
        frames = batch["inconsistent", "frames"]
        inputs = video_inputs(batch, "inconsistent")
        for index, concept in enumerate(batch["concept"].tolist()):
            name = concept_names[concept]
            if name not in self.examples:  # the first probe of each concept, fixed over training
                self.examples[name] = {
                    key: value[index].detach().cpu()
                    for key, value in {"frames": frames, **inputs}.items()
                }

    def on_validation_epoch_end(self, trainer, pl_module) -> None:
        if trainer.sanity_checking or not trainer.is_global_zero or not self.examples:
            return
        experiment = getattr(trainer.logger, "experiment", None)
        if experiment is None or not hasattr(experiment, "add_image"):
            return
        for concept, example in self.examples.items():
            video = {key: value[: self.max_frames][None].to(pl_module.device)
                     for key, value in example.items()}
            frames = example["frames"][: self.max_frames]
            with torch.no_grad():
                expected = pl_module.expected_frames(video.pop("frames"), **video)[0]
            strip = torch.cat([specs.to_model_input(frames), expected.float().cpu().clamp(0, 1)], dim=-2)
            # [T, 3, 2H, W] -> [3, 2H, T*W]: input row above expectation row.
            image = strip.permute(1, 2, 0, 3).reshape(3, strip.shape[-2], -1)
            experiment.add_image(f"expected/{concept}", image, global_step=trainer.global_step)
