"""Callbacks, one concern each: VOE statistics of the validation probes over training, image
strips of what the model expected to see, the VOE report of a ``test`` run, and a checkpoint
of the final training step."""

from __future__ import annotations

import functools
import json
from collections import defaultdict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.utilities import rank_zero_warn
from rich.console import Console
from rich.table import Table
from tensordict import TensorDictBase

from voe_lightning import cues, specs
from voe_lightning.causality import Causality, check_prefix
from voe_lightning.external.evaluation import evaluate
from voe_lightning.model.base import SurpriseModel, video_inputs
from voe_lightning.probe_datamodule import probe_datamodule
from voe_lightning.report import write_report
from voe_lightning.report.figures import PredictionExample
from voe_lightning.report.results import (
    FIRST_DIFFERENCE,
    PROBE_OUTPUT_KEYS,
    PairResults,
    as_numpy,
)
from voe_lightning.runs import RunConfig
from voe_lightning.statistics import ALPHA, POOLED, POOLED_VARIANTS, check_alpha
from voe_lightning.statistics_format import CONSOLE, format_alpha, row_text
from voe_lightning.store_shards import write_whole
from voe_lightning.streaming_statistics import PairedSurpriseStats, pooled_values
from voe_lightning.surprise_window import SurpriseWindow, video_surprise
from voe_lightning.surprise_window import surprise_window as parse_window
from voe_lightning.verdicts import concept_verdicts, pair_groups


def _names(trainer: L.Trainer, user: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The DataModule's concept and variant names (refused unless it is a ProbeDataModule)."""
    datamodule = probe_datamodule(trainer, user)
    return tuple(datamodule.concept_names), tuple(datamodule.variant_names)


class VOEProbeCallback(L.Callback):
    """Every validation run (set its frequency with ``trainer.val_check_interval``, in training
    steps) streams each probe pair's relative surprise into one PairedSurpriseStats per
    concept/variant, then logs ``voe/<concept>/<variant>/{relative_surprise,t,p_value,accuracy,n}``.
    A concept with a standard and a counterbalanced variant also gets
    ``voe/<concept>/pooled/...``: the stratified test of its two variants
    (``streaming_statistics.pooled_values``, from their float64 sums, so exact under DDP as
    they are).
    At the end of ``fit`` it prints the last table with each concept's verdict at ``alpha``
    (None: ``statistics.ALPHA``; the CLI gives the run's ``alpha`` from configs/base.yaml).
    A ``surprise_window`` other than all frames (``surprise_window.surprise_window``; the CLI
    gives the run's) logs the same statistics of each video's surprise summed over that window
    beside them, as ``voe_window/...``. Each validation run also checks causality
    (``causality.check_prefix``): ``causality`` holds the last run's finding; where surprise
    differs through the pairs' manipulation frame it warns, and the table gives no verdict."""

    STATISTICS = ("relative_surprise", "t", "p_value", "accuracy", "n")

    def __init__(
        self,
        print_table: bool = True,
        alpha: float | None = None,
        surprise_window: str | dict[str, Any] | None = None,
    ):
        super().__init__()
        self.print_table = print_table
        self.alpha = ALPHA if alpha is None else check_alpha(alpha)
        window = parse_window(surprise_window)
        #: The windows whose statistics are logged, by log prefix: all frames first.
        self.windows = {
            "voe": SurpriseWindow(),
            **({} if window.all_frames else {"voe_window": window}),
        }
        self.metrics: dict[tuple[str, str, str], PairedSurpriseStats] = {}
        self.last: dict[tuple[str, str], dict[str, float]] = {}
        self.causality: Causality | None = None
        self._causality = Causality()

    def on_validation_epoch_start(self, trainer, pl_module) -> None:
        cases = probe_datamodule(trainer, type(self).__name__).probe_cases("val")
        # Create every metric up front so all DDP ranks hold the same states.
        for prefix in self.windows:
            for case in cases:
                self._metric((prefix, *case), pl_module.device)
        for metric in self.metrics.values():
            metric.reset()
        self._causality = Causality()

    def _metric(self, key: tuple[str, str, str], device: torch.device) -> PairedSurpriseStats:
        if key not in self.metrics:
            self.metrics[key] = PairedSurpriseStats().to(device)
        return self.metrics[key]

    def on_validation_batch_end(
        self, trainer, pl_module, outputs, batch, batch_idx, dataloader_idx=0
    ) -> None:
        if not outputs:
            return
        concept_names, variant_names = _names(trainer, type(self).__name__)
        self._causality = self._causality.merge(
            check_prefix(
                outputs["surprise_consistent"],
                outputs["surprise_inconsistent"],
                outputs["manipulation_frame"],
                outputs.get("first_difference"),
            )
        )
        groups = defaultdict(list)
        for index, (c, v) in enumerate(
            zip(outputs["concept"].tolist(), outputs["variant"].tolist())
        ):
            groups[(concept_names[c], variant_names[v])].append(index)
        for prefix, window in self.windows.items():
            inconsistent, consistent = (
                _window_sum(outputs, side, window) for side in ("inconsistent", "consistent")
            )
            for case, rows in groups.items():
                rows = torch.tensor(rows, device=inconsistent.device)
                self._metric((prefix, *case), pl_module.device).update(
                    inconsistent[rows], consistent[rows]
                )

    def on_validation_epoch_end(self, trainer, pl_module) -> None:
        if trainer.sanity_checking:
            return
        # Every rank's pairs (under DDP each rank scored its own), as the statistics are.
        self.causality = functools.reduce(Causality.merge, _gather(self._causality))
        if not self.causality.causal:
            rank_zero_warn(f"validation at step {trainer.global_step}: {self.causality.line()}")
        for prefix in self.windows:
            results = self._results(prefix)
            for (concept, variant), values in results.items():
                for statistic in self.STATISTICS:
                    pl_module.log(
                        f"{prefix}/{concept}/{variant}/{statistic}",
                        values[statistic],
                        sync_dist=False,
                    )
            if prefix == "voe":
                self.last = results

    def _results(self, prefix: str) -> dict[tuple[str, str], dict[str, float]]:
        """The statistics of the window logged under ``prefix``, per concept/variant with the
        pooled rows, of the cases with at least two pairs so far."""
        computed = {}
        for (window, *case), metric in self.metrics.items():
            if window != prefix:
                continue
            try:  # called on every rank alike: compute() syncs the states under DDP
                computed[tuple(case)] = {k: float(v) for k, v in metric.compute().items()}
            except ValueError:  # fewer than two pairs of this case so far
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

    def on_fit_end(self, trainer, pl_module) -> None:
        if self.print_table and self.last and trainer.is_global_zero:
            console = Console()
            if not console.is_terminal:  # logs and pipes: do not cut the table at 80 columns
                console.width = 120
            title = f"VOE on validation probes, step {trainer.global_step}"
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
    return video_surprise(outputs[f"surprise_{side}"], window, first)


def voe_table(
    results: dict[tuple[str, str], dict[str, float]],
    title: str,
    alpha: float = ALPHA,
    causality: Causality | None = None,
) -> Table:
    """A rich table of relative surprise, t, p and accuracy per concept/variant (pooled rows
    bold: the stratified test), alpha in its title and p header, with each concept's verdict
    (``verdicts.concept_verdicts``, withheld where ``causality`` failed, whose line is the
    caption) on its first row."""
    verdicts = {v.concept: v for v in concept_verdicts(results, alpha, causality)}
    table = Table(
        title=f"{title} ({format_alpha(alpha)})",
        caption=causality.line() if causality is not None else None,
    )
    for column in (
        "concept",
        "variant",
        "n",
        "relative surprise",
        "t",
        f"p (one-tailed, * < {alpha:g})",
        "accuracy",
        "verdict",
    ):
        justify = "left" if column in ("concept", "variant", "verdict") else "right"
        table.add_column(column, justify=justify, overflow="fold")
    keys = list(results)
    for index, ((concept, variant), values) in enumerate(results.items()):
        cells = row_text(values, CONSOLE, alpha)
        first = index == 0 or keys[index - 1][0] != concept
        last = index + 1 == len(keys) or keys[index + 1][0] != concept
        verdict = verdicts[concept]
        text = verdict.text() if first else ""
        if first and verdict.voe is not None:
            text = f"[green]{text}[/green]" if verdict.voe else f"[red]{text}[/red]"
        table.add_row(
            concept if first else "",
            variant,
            cells.n,
            cells.mean,
            cells.t,
            cells.p + cells.star,
            cells.accuracy,
            text,
            style="bold" if variant == POOLED else None,
            end_section=last,
        )
    return table


class FinalStepCheckpoint(ModelCheckpoint):
    """Lightning's ``ModelCheckpoint`` that also saves the step training ends at. Lightning's
    keeps ``last.ckpt`` at the last *scheduled* step, so ``max_steps: 3600`` with
    ``every_n_train_steps: 2000`` would leave the step-2,000 model there for ``test``."""

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_train_end(trainer, pl_module)
        # Lightning's own rule: not under fast_dev_run, not outside fit, not a step already saved.
        if not self._should_skip_saving_checkpoint(trainer):
            candidates = self._monitor_candidates(trainer)
            self._save_topk_checkpoint(trainer, candidates)
            self._save_last_checkpoint(trainer, candidates)


def _first_frames(video_input: Any, count: int) -> Any:
    """The first ``count`` frames of one video's input: a tensor [T, ...], or a TensorDict of
    per-frame leaves (``objects``, whose batch dims end before T)."""
    if isinstance(video_input, TensorDictBase):
        return video_input.apply(lambda leaf: leaf[:count])
    return video_input[:count]


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
        concept_names, _ = _names(trainer, type(self).__name__)
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
            video = {
                key: _first_frames(value, self.max_frames)[None].to(pl_module.device)
                for key, value in example.items()
            }
            frames = example["frames"][: self.max_frames]
            with torch.no_grad():
                expected = pl_module.expected_frames(video.pop("frames"), **video)[0]
            strip = torch.cat(
                [specs.to_model_input(frames), expected.float().cpu().clamp(0, 1)], dim=-2
            )
            # [T, 3, 2H, W] -> [3, 2H, T*W]: input row above expectation row.
            image = strip.permute(1, 2, 0, 3).reshape(3, strip.shape[-2], -1)
            experiment.add_image(f"expected/{concept}", image, global_step=trainer.global_step)


# ----------------------------------------------------------------------------- report


def _stacked(
    videos: list[dict[str, torch.Tensor]], device: torch.device
) -> dict[str, torch.Tensor]:
    """Kept videos (frames and, where the batch had them, mask and camera) as one batch."""
    return {key: torch.stack([video[key] for video in videos]).to(device) for key in videos[0]}


def _gather(value: Any) -> list[Any]:
    """All ranks' values under torch.distributed (DDP test), else [value]."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1:
        gathered: list[Any] = [None] * dist.get_world_size()
        dist.all_gather_object(gathered, value)
        return gathered
    return [value]


class VOEReportCallback(L.Callback):
    """Collects ``test_step`` outputs (the ``probe_step`` dict) and, at the end of ``test``,
    writes the VOE report into ``out_dir`` or the run directory (``trainer.log_dir``). Keeps
    up to ``max_prediction_examples`` inconsistent probes per concept/variant for
    predictions_<concept>.png (``pl_module.expected_frames``) and ``tsne_pairs``
    object-persistence pairs, standard and counterbalanced alternately, for the t-SNE figure
    (``pl_module.trajectories``). Tests are at ``alpha`` (None: ``statistics.ALPHA``; the CLI
    gives the run's ``alpha`` from configs/base.yaml). With ``cue_audit`` it scores the physics-blind cues of every
    test batch's pairs (``voe_lightning.cues``, on the batch's device), so the cue rows of
    cues.md/cues.csv share the model's pairs and n. Names are decoded with the
    ProbeDataModule's ``concept_names`` / ``variant_names``. summary.json's ``source`` names
    the config file saved for the run, the checkpoint tested, its global step, the DataModule,
    its data root (and seed offset and probe store: ``ProbeDataModule.probe_source``) and
    concepts; summary.md's first line too.
    ``surprise_window`` (``surprise_window.surprise_window``: ``all``, the paper's, or
    ``{start: first_difference, frames: k}``) adds the tests of each video's surprise summed
    over that window beside those over all frames (None: all frames only; the CLI gives the
    run's ``surprise_window``). With ``priors_alone`` (the positive control's config sets it)
    the CLI's ``test`` first tests the same config at initialization on the same probes
    (``null.priors_alone``: learned parts untrained, same seed, given structure as
    configured) and hands its summary to ``untrained``; the report carries its verdicts and t
    per variant beside the model's, labelled "priors alone (untrained)". After the test,
    ``summary`` holds the rows, ``report_dir`` the directory written and ``causality`` the
    report's causality check (no verdict where it failed)."""

    def __init__(
        self,
        out_dir: str | None = None,
        max_prediction_examples: int = 1,
        tsne_pairs: int = 2,
        alpha: float | None = None,
        bootstrap: int = 2000,
        seed: int = 0,
        cue_audit: bool = True,
        surprise_window: str | dict[str, Any] | None = None,
        priors_alone: bool = False,
    ) -> None:
        if max_prediction_examples < 0 or tsne_pairs < 0:
            raise ValueError(
                "max_prediction_examples and tsne_pairs must be >= 0, got "
                f"{max_prediction_examples} and {tsne_pairs}"
            )
        self.out_dir = out_dir
        self.max_prediction_examples = max_prediction_examples
        self.tsne_pairs = tsne_pairs
        self.alpha = ALPHA if alpha is None else check_alpha(alpha)
        self.bootstrap, self.seed = bootstrap, seed
        self.cue_audit = cue_audit
        self.surprise_window = parse_window(surprise_window)
        self.priors_alone = priors_alone
        #: The untrained copy's summary.json document (``null.priors_alone``), set by the CLI.
        self.untrained: dict[str, Any] | None = None
        self.summary: list[dict[str, Any]] | None = None
        self.report_dir: Path | None = None
        self.causality: Causality | None = None
        self._failed = self._ended = False
        self._checkpoint_step: int | None = None
        self._reset()

    def _reset(self) -> None:
        self._outputs: list[dict[str, np.ndarray]] = []
        self._cues: list[cues.CueAudit] = []
        self._examples: dict[tuple[int, int], list[dict[str, Any]]] = {}
        self._tsne: dict[int, list[dict[str, Any]]] = {}

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if not isinstance(pl_module, SurpriseModel):
            raise TypeError(
                f"VOEReportCallback needs a SurpriseModel (surprise, expected_frames "
                f"and trajectories, voe_lightning.model.base); got "
                f"{type(pl_module).__name__}"
            )
        self.summary, self.report_dir, self._failed, self._ended = None, None, False, False
        self.causality = None

    def on_exception(
        self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException
    ) -> None:
        self._failed = True

    def on_load_checkpoint(
        self, trainer: L.Trainer, pl_module: L.LightningModule, checkpoint: dict[str, Any]
    ) -> None:
        self._checkpoint_step = checkpoint.get("global_step")

    def _source(self, trainer: L.Trainer) -> dict[str, Any]:
        """What the report is made from: checkpoint (None: the model as built), its global
        step, the DataModule's class, where its probes come from (``probe_source``: data root;
        ours, the seed offset and probe store too), the concepts of its test pairs, and the
        config file the CLI saved for this run (``runs.RunConfig``; None: none saved)."""
        datamodule = probe_datamodule(trainer, type(self).__name__)
        configs = [
            callback.config_path
            for callback in trainer.callbacks
            if isinstance(callback, RunConfig) and callback.config_path is not None
        ]
        return {
            "config": str(configs[0]) if configs else None,
            "checkpoint": str(trainer.ckpt_path) if trainer.ckpt_path else None,
            "global_step": self._checkpoint_step if trainer.ckpt_path else None,
            "datamodule": f"{type(datamodule).__module__}.{type(datamodule).__qualname__}",
            **datamodule.probe_source(),
            "concepts": sorted({concept for concept, _ in datamodule.probe_cases("test")}),
        }

    def teardown(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        # Lightning skips the whole test loop (and on_test_end) when the loaders are empty.
        if stage == "test" and not self._ended and not self._failed:
            self._no_results()

    @staticmethod
    def _no_results() -> None:
        raise RuntimeError(
            "VOEReportCallback collected no probe results: the test dataloaders yielded no "
            "probe pairs (does the DataModule have test probes for its concepts?)"
        )

    def on_test_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._reset()
        self._concept_names, self._variant_names = _names(trainer, type(self).__name__)

    def on_test_batch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
        dataloader_idx: int = 0,
    ) -> None:
        if not isinstance(outputs, Mapping):
            raise TypeError(
                f"VOEReportCallback needs test_step to return the probe_step dict "
                f"with {list(PROBE_OUTPUT_KEYS)}; got {type(outputs).__name__}"
            )
        missing = [key for key in PROBE_OUTPUT_KEYS if key not in outputs]
        if missing:
            raise KeyError(f"test_step output lacks {missing} (needs {list(PROBE_OUTPUT_KEYS)})")
        stored = {
            key: as_numpy(outputs[key], None)
            for key in (*PROBE_OUTPUT_KEYS, FIRST_DIFFERENCE)
            if key in outputs
        }
        self._outputs.append(stored)
        if self.cue_audit:
            self._cues.append(
                cues.CueAudit.score_batch(batch, self._concept_names, self._variant_names)
            )
        self._keep_examples(stored, batch)

    def _keep_examples(self, stored: Mapping[str, np.ndarray], batch: Any) -> None:
        persistence = (
            self._concept_names.index("object_persistence")
            if "object_persistence" in self._concept_names
            else None
        )
        for i, (concept, variant) in enumerate(zip(stored["concept"], stored["variant"])):
            concept, variant = int(concept), int(variant)
            meta = {
                "concept": concept,
                "variant": variant,
                "seed": int(stored["seed"][i]),
                "manipulation_frame": int(stored["manipulation_frame"][i]),
            }
            kept = self._examples.setdefault((concept, variant), [])
            videos = {
                side: {"frames": batch[side, "frames"][i].cpu().clone()}
                | {
                    name: value[i].cpu().clone()
                    for name, value in video_inputs(batch, side).items()
                }
                for side in ("consistent", "inconsistent")
            }
            if len(kept) < self.max_prediction_examples:
                kept.append(meta | {"inconsistent": videos["inconsistent"]})
            tsne = self._tsne.setdefault(variant, []) if concept == persistence else None
            if tsne is not None and len(tsne) < self.tsne_pairs:
                tsne.append(meta | videos)

    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        gathered = _gather((self._outputs, self._examples, self._tsne, self._cues))
        self._ended = True  # on every rank; only rank zero writes the report
        # trainer.log_dir broadcasts under DDP: every rank must ask for it.
        out_dir = self.out_dir or trainer.log_dir or trainer.default_root_dir
        if not trainer.is_global_zero:
            return
        outputs = [output for rank in gathered for output in rank[0]]
        if not outputs:
            self._no_results()
        results = PairResults.from_probe_outputs(outputs, self._concept_names, self._variant_names)
        examples = [e for rank in gathered for kept in rank[1].values() for e in kept]
        tsne = [e for rank in gathered for kept in rank[2].values() for e in kept]
        cue_audit = (
            cues.CueAudit.concatenate(a for rank in gathered for a in rank[3])
            if self.cue_audit
            else None
        )
        was_training = pl_module.training
        pl_module.eval()
        try:
            with torch.no_grad():
                predictions = self._predictions(pl_module, examples)
                trajectories, labels = self._trajectories(pl_module, tsne)
        finally:
            pl_module.train(was_training)
        self.summary = write_report(
            results,
            out_dir,
            predictions,
            trajectories,
            trajectory_labels=labels,
            cue_audit=cue_audit,
            alpha=self.alpha,
            bootstrap=self.bootstrap,
            seed=self.seed,
            surprise=pl_module.SURPRISE,
            source=self._source(trainer),
            window=self.surprise_window,
            priors_alone=self.untrained,
        )
        self.report_dir = Path(out_dir) / "voe_report"
        self.causality = results.causality
        self._write_benchmark_metrics(trainer, outputs)

    def _write_benchmark_metrics(self, trainer: L.Trainer, outputs: list[dict[str, Any]]) -> None:
        """External benchmarks (IntPhys, Physical Concepts, IntPhys 2) add their own published
        metrics and files (``external.evaluation``, over the DataModule's ``external_pairs``),
        written whole (``store_shards.write_whole``)."""
        pairs = probe_datamodule(trainer, type(self).__name__).external_pairs()
        if pairs is None:
            return
        merged = {
            key: np.concatenate([output[key] for output in outputs]) for key in PROBE_OUTPUT_KEYS
        }
        metrics, files = evaluate(pairs, merged, alpha=self.alpha, bootstrap=self.bootstrap)
        path = self.report_dir / "benchmark_metrics.json"
        write_whole(
            {
                path: json.dumps(metrics, indent=2, default=lambda v: v.item()) + "\n",
                **{self.report_dir / name: text for name, text in files.items()},
            }
        )
        print(f"benchmark metrics written to {path}")
        for name in files:
            print(f"{name} written to {self.report_dir / name}")

    def _predictions(
        self, pl_module: L.LightningModule, examples: list[dict[str, Any]]
    ) -> list[PredictionExample]:
        if not examples:
            return []
        video = _stacked([e["inconsistent"] for e in examples], pl_module.device)
        expected = pl_module.expected_frames(**video).float().cpu().numpy()
        return [
            PredictionExample(
                concept=self._concept_names[e["concept"]],
                variant=self._variant_names[e["variant"]],
                seed=e["seed"],
                manipulation_frame=e["manipulation_frame"],
                frames=e["inconsistent"]["frames"].numpy(),
                expected=expected[i],
            )
            for i, e in enumerate(examples)
        ]

    def _trajectories(self, pl_module: L.LightningModule, tsne: list[dict[str, Any]]):
        # Interleave variants (standard, counterbalanced, standard, ...) up to tsne_pairs.
        by_variant: dict[int, list[dict[str, Any]]] = {}
        for e in tsne:
            by_variant.setdefault(e["variant"], []).append(e)
        order = sorted(by_variant, key=lambda v: self._variant_names[v] != "standard")
        chosen = [
            by_variant[v][i]
            for i in range(self.tsne_pairs)
            for v in order
            if i < len(by_variant[v])
        ][: self.tsne_pairs]
        if len(chosen) < 2:
            if self.tsne_pairs:
                rank_zero_warn(
                    "fewer than 2 object-persistence probe pairs in the test set; "
                    "tsne_object_persistence.png not written"
                )
            return None, None
        trajectories = {}
        for video in ("consistent", "inconsistent"):
            courses = pl_module.trajectories(
                **_stacked([e[video] for e in chosen], pl_module.device)
            )
            trajectories[video] = {k: v.float().cpu().numpy() for k, v in courses.items()}
        labels = [f"{self._variant_names[e['variant']]} (seed {e['seed']})" for e in chosen]
        return trajectories, labels
