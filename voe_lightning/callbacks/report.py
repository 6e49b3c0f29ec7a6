"""``VOEReportCallback``: the VOE report of a ``test`` run (tables, figures, summary.json). It
holds the run's hooks and composes one collaborator per concern: the probe outputs and cue
scores of each batch (``report_batches``), the figures' example videos (``report_examples``),
the report's source (``report_source``), the report files themselves (``report.write_report``,
the priors-alone rows among them) and an external benchmark's metrics
(``report_benchmark``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L

from voe_lightning.audit.followers import features_read
from voe_lightning.callbacks.common import (
    ProbeOutcome,
    RunAlpha,
    check_finite_surprise,
    gather_objects,
    probe_names,
)
from voe_lightning.callbacks.report_batches import CueScores, ProbeOutputs
from voe_lightning.callbacks.report_benchmark import write_benchmark_metrics
from voe_lightning.callbacks.report_examples import ExampleVideos
from voe_lightning.callbacks.report_source import report_source
from voe_lightning.model.base import SurpriseModel, inputs_read_by
from voe_lightning.report import ReportInputs, write_report
from voe_lightning.report.pairs import PairResults
from voe_lightning.stats.causality import Causality
from voe_lightning.stats.surprise_window import SurpriseWindow


class VOEReportCallback(RunAlpha, L.Callback):
    """Collects ``test_step`` outputs (the ``probe_step`` dict, ``ProbeOutputs``) and, at the
    end of ``test``, writes the VOE report into ``out_dir`` or the run directory
    (``trainer.log_dir``). Keeps up to ``max_prediction_examples`` inconsistent probes per
    concept/variant for predictions_<concept>.png (``pl_module.expected_frames``) and
    ``tsne_pairs`` object-persistence pairs, standard and counterbalanced alternately, for the
    t-SNE figure (``pl_module.trajectories``; ``ExampleVideos``). Tests are at ``alpha``, the
    run's significance level (the CLI gives the run's ``alpha``, configs/base.yaml). With
    ``cue_audit`` it scores the physics-blind cues of every test batch's pairs (``CueScores``:
    ``voe_lightning.audit.cues``, on the batch's device), so the cue rows of cues.md/cues.csv
    share the model's pairs and n. Names are decoded with the ProbeDataModule's
    ``concept_names`` / ``variant_names``. summary.json's ``source`` (``report_source``) names
    the config file saved for the run, the checkpoint tested, its global step, the DataModule,
    its data root (and seed offset and probe store: ``ProbeDataModule.probe_source``) and
    concepts; summary.md's first line too. An external benchmark's DataModule adds its
    published metrics (``write_benchmark_metrics``).
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
        alpha: float | None = None,
        max_prediction_examples: int = 1,
        tsne_pairs: int = 2,
        bootstrap: int = 2000,
        seed: int = 0,
        cue_audit: bool = True,
        surprise_window: SurpriseWindow | None = None,
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
        super().__init__(alpha)
        self.bootstrap, self.seed = bootstrap, seed
        self.cue_audit = cue_audit
        self.surprise_window = surprise_window or SurpriseWindow()
        self.priors_alone = priors_alone
        #: The untrained copy's summary.json document (``null.priors_alone``), set by the CLI.
        self.untrained: dict[str, Any] | None = None
        self.summary: list[dict[str, Any]] | None = None
        self.report_dir: Path | None = None
        self.causality: Causality | None = None
        self._failed = self._ended = False
        self._checkpoint_step: int | None = None
        self._reset((), ())

    def _reset(
        self,
        concept_names: tuple[str, ...],
        variant_names: tuple[str, ...],
        followers: tuple[str, ...] = (),
    ) -> None:
        """Fresh collaborators for a test of a DataModule with these names, auditing the
        followers of the model's inputs (``followers``)."""
        self._concept_names, self._variant_names = concept_names, variant_names
        self._outputs = ProbeOutputs()
        self._cues = CueScores(concept_names, variant_names, followers)
        self._examples = ExampleVideos(
            self.max_prediction_examples, self.tsne_pairs, concept_names, variant_names
        )

    @property
    def outcome(self) -> ProbeOutcome:
        """The last test's causality check and the report folder it wrote."""
        return ProbeOutcome(self.causality, self.report_dir)

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
        followers = features_read(inputs_read_by(pl_module))
        self._reset(*probe_names(trainer, type(self).__name__), followers)

    def on_test_batch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
        dataloader_idx: int = 0,
    ) -> None:
        stored = self._outputs.add(outputs)
        check_finite_surprise(stored, self._concept_names, self._variant_names)
        if self.cue_audit:
            self._cues.add(batch)
        self._examples.add(stored, batch, inputs_read_by(pl_module))

    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        gathered = gather_objects((self._outputs.kept, self._examples.kept, self._cues.kept))
        self._ended = True  # on every rank; only rank zero writes the report
        # trainer.log_dir broadcasts under DDP: every rank must ask for it.
        out_dir = self.out_dir or trainer.log_dir or trainer.default_root_dir
        if not trainer.is_global_zero:
            return
        assert isinstance(pl_module, SurpriseModel)  # setup refused any other module
        outputs = [output for rank in gathered for output in rank[0]]
        if not outputs:
            self._no_results()
        results = PairResults.from_probe_outputs(outputs, self._concept_names, self._variant_names)
        cue_audit = CueScores.audit(rank[2] for rank in gathered) if self.cue_audit else None
        predictions, trajectories, labels = self._examples.figure_inputs(
            pl_module, [rank[1] for rank in gathered]
        )
        user = type(self).__name__
        inputs = ReportInputs(
            results,
            alpha=self.alpha,
            bootstrap=self.bootstrap,
            seed=self.seed,
            predictions=predictions,
            trajectories=trajectories,
            trajectory_labels=labels,
            cue_audit=cue_audit,
            surprise=pl_module.SURPRISE,
            source=report_source(trainer, self._checkpoint_step, user),
            window=self.surprise_window,
            priors_alone=self.untrained,
        )
        self.summary = write_report(inputs, out_dir)
        self.report_dir = Path(out_dir) / "voe_report"
        self.causality = results.causality
        write_benchmark_metrics(
            trainer,
            outputs,
            self.report_dir,
            alpha=self.alpha,
            bootstrap=self.bootstrap,
            user=user,
        )
