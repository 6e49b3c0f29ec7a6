"""``FinalStepCheckpoint``: a checkpoint of the step training ends at."""

from __future__ import annotations

import lightning as L
from lightning.pytorch.callbacks import ModelCheckpoint


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
