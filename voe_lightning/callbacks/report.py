"""``VOEReportCallback``: the VOE report of a ``test`` run (tables, figures, summary.json)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.utilities import rank_zero_warn

from voe_lightning.audit import cues
from voe_lightning.callbacks.common import gather_objects, probe_names
from voe_lightning.causality import Causality
from voe_lightning.data.store_shards import write_whole
from voe_lightning.external.evaluation import evaluate
from voe_lightning.model.base import SurpriseModel, video_inputs
from voe_lightning.probe_datamodule import probe_datamodule
from voe_lightning.report import write_report
from voe_lightning.report.figures import PredictionExample
from voe_lightning.report.pairs import (
    FIRST_DIFFERENCE,
    PROBE_OUTPUT_KEYS,
    PairResults,
    as_numpy,
)
from voe_lightning.runs import RunConfig
from voe_lightning.stats.statistics import ALPHA, check_alpha
from voe_lightning.stats.surprise_window import surprise_window as parse_window


def _stacked(
    videos: list[dict[str, torch.Tensor]], device: torch.device
) -> dict[str, torch.Tensor]:
    """Kept videos (frames and, where the batch had them, mask and camera) as one batch."""
    return {key: torch.stack([video[key] for video in videos]).to(device) for key in videos[0]}


class VOEReportCallback(L.Callback):
    """Collects ``test_step`` outputs (the ``probe_step`` dict) and, at the end of ``test``,
    writes the VOE report into ``out_dir`` or the run directory (``trainer.log_dir``). Keeps
    up to ``max_prediction_examples`` inconsistent probes per concept/variant for
    predictions_<concept>.png (``pl_module.expected_frames``) and ``tsne_pairs``
    object-persistence pairs, standard and counterbalanced alternately, for the t-SNE figure
    (``pl_module.trajectories``). Tests are at ``alpha`` (None: ``statistics.ALPHA``; the CLI
    gives the run's ``alpha`` from configs/base.yaml). With ``cue_audit`` it scores the physics-blind cues of every
    test batch's pairs (``voe_lightning.audit.cues``, on the batch's device), so the cue rows of
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
        self._concept_names, self._variant_names = probe_names(trainer, type(self).__name__)

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
        gathered = gather_objects((self._outputs, self._examples, self._tsne, self._cues))
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
