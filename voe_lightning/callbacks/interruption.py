"""A preempted or interrupted ``fit`` saves where it stopped and says so: SIGTERM (a cluster's
preemption) and SIGINT (Ctrl-C) stop training at the end of the current step through
Lightning's own SIGTERM handling, and ``InterruptCheckpoint`` saves a resumable last.ckpt
there; the CLI then exits with 128 + the signal's number instead of 0. ``validate``, ``test``
and ``predict`` have nothing to resume: SIGTERM stops them at once (Lightning's handler only
sets a flag, which its loops read between batches and its predict loop never), so ``kill``
and ``timeout`` stop a long evaluation. Ctrl-C anywhere else stays a KeyboardInterrupt, which
Lightning would answer with a line of its own and exit status 1 (``ctrl_c_kept``)."""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import lightning as L
from lightning.pytorch.trainer.states import TrainerFn
from lightning.pytorch.utilities.exceptions import SIGTERMException

from voe_lightning.callbacks.checkpoint_io import use_whole_checkpoints
from voe_lightning.runs import LAST_CHECKPOINT

#: The logger of Lightning's ``rank_zero_info``, which says it caught a KeyboardInterrupt.
LIGHTNING_INFO = "lightning.pytorch.utilities.rank_zero"
#: What that logger then says.
LIGHTNING_CTRL_C = "Detected KeyboardInterrupt"


@contextlib.contextmanager
def ctrl_c_kept() -> Iterator[None]:
    """Within, Ctrl-C in a trainer's method stays the KeyboardInterrupt it is: Lightning
    catches it, logs a line, ignores SIGINT from then on and calls ``sys.exit(1)``; that line
    is left out, SIGINT's handler put back and the KeyboardInterrupt raised again, for the CLI
    to say in one line what was kept."""
    handler = signal.getsignal(signal.SIGINT)
    logger = logging.getLogger(LIGHTNING_INFO)
    logger.addFilter(_not_lightning_ctrl_c)
    try:
        yield
    except SystemExit as exit:
        if exit.code != 1 or not isinstance(exit.__context__, KeyboardInterrupt):
            raise
        raise exit.__context__ from None
    finally:
        logger.removeFilter(_not_lightning_ctrl_c)
        if handler is not None and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, handler)


def _not_lightning_ctrl_c(record: logging.LogRecord) -> bool:
    """Whether a log record is other than Lightning's line on a KeyboardInterrupt."""
    return LIGHTNING_CTRL_C not in record.getMessage()


class InterruptCheckpoint(L.Callback):
    """While training runs, SIGINT is handled as SIGTERM (Lightning then raises
    ``SIGTERMException`` once the step in progress has ended, so the loops' state is whole);
    on that exception the trainer's full state is saved as last.ckpt in the run's checkpoint
    folder, ready for ``fit --ckpt_path <it>`` (or ``last``). A second Ctrl-C stops at once,
    saving nothing. During ``validate``, ``test`` and ``predict``, SIGTERM raises
    ``SIGTERMException`` at once (nothing to save). After the exception, ``signal_name`` and
    ``saved`` say what happened. It also writes every checkpoint of the run whole
    (``checkpoint_io.WholeCheckpointIO``)."""

    def __init__(self) -> None:
        self.signal_name: str | None = None
        self.saved: Path | None = None
        self._previous: dict[int, Any] = {}

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        """Every checkpoint of the run, this one's and ModelCheckpoint's, is written whole
        (``checkpoint_io.WholeCheckpointIO``: never a truncated file on a full disk)."""
        use_whole_checkpoints(trainer)

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.signal_name, self.saved = None, None
        # Lightning's SIGTERM handler is in place by now: it only sets a flag the loops read.
        terminate = signal.getsignal(signal.SIGTERM)
        if not callable(terminate) or threading.current_thread() is not threading.main_thread():
            return  # no Lightning handler to hand over to, or handlers cannot be set here
        self._previous = {
            number: signal.getsignal(number) for number in (signal.SIGTERM, signal.SIGINT)
        }

        def on_signal(number: int, frame: Any) -> None:
            if self.signal_name is None:
                self.signal_name = signal.Signals(number).name
            signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C: now
            terminate(number, frame)

        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._restore_handlers()

    # ------------------------------------------------ validate, test, predict: stop at once
    def _stop_on_sigterm(self, trainer: L.Trainer) -> None:
        """Outside ``fit``, SIGTERM raises ``SIGTERMException`` where the evaluation is (a
        batch, the report): there is no state to save, and the flag Lightning's handler sets
        is read only between batches (never in the last one, the report or predict)."""
        if trainer.state.fn == TrainerFn.FITTING or self._previous:
            return
        if threading.current_thread() is not threading.main_thread():
            return
        self.signal_name, self.saved = None, None
        self._previous = {signal.SIGTERM: signal.getsignal(signal.SIGTERM)}

        def on_signal(number: int, frame: Any) -> None:
            self.signal_name = signal.Signals(number).name
            self._restore_handlers()
            raise SIGTERMException

        signal.signal(signal.SIGTERM, on_signal)

    def on_validation_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._stop_on_sigterm(trainer)

    def on_test_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._stop_on_sigterm(trainer)

    def on_predict_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._stop_on_sigterm(trainer)

    def _evaluation_end(self, trainer: L.Trainer) -> None:
        if trainer.state.fn != TrainerFn.FITTING:
            self._restore_handlers()

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._evaluation_end(trainer)

    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._evaluation_end(trainer)

    def on_predict_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._evaluation_end(trainer)

    def on_exception(
        self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException
    ) -> None:
        self._restore_handlers()
        if not isinstance(exception, SIGTERMException) or trainer.state.fn != TrainerFn.FITTING:
            return
        self.signal_name = self.signal_name or "SIGTERM"
        self.saved = self.checkpoint_path(trainer)
        trainer.save_checkpoint(self.saved)

    @staticmethod
    def checkpoint_path(trainer: L.Trainer) -> Path:
        """last.ckpt in the ModelCheckpoint's folder, else in ``<log_dir>/checkpoints``."""
        callback = trainer.checkpoint_callback
        folder = (
            getattr(callback, "dirpath", None)
            or Path(trainer.log_dir or trainer.default_root_dir) / "checkpoints"
        )
        return Path(folder) / LAST_CHECKPOINT

    def _restore_handlers(self) -> None:
        for number, handler in self._previous.items():
            signal.signal(number, handler)
        self._previous = {}

    def exit_code(self) -> int:
        """The shell's code for death by the signal received: 128 + its number."""
        return 128 + int(signal.Signals[self.signal_name or "SIGTERM"])

    def stopped(self, subcommand: str, step: int) -> str:
        """The line saying what stopped ``subcommand`` (a fit: at ``step``) and what it left:
        a fit's resumable checkpoint and how to continue from it."""
        if subcommand != "fit":
            return (
                f"{subcommand} stopped by {self.signal_name or 'SIGTERM'}; nothing written "
                "(no report, no predictions)"
            )
        saved = (
            f"saved a resumable checkpoint {self.saved}: continue with "
            f"`fit --ckpt_path {self.saved}`"
            if self.saved
            else "nothing saved"
        )
        return f"fit stopped by {self.signal_name or 'SIGTERM'} at step {step}; {saved}"
