"""The Lightning callbacks, one module each, re-exported here because configs and saved runs
name them by this package (``voe_lightning.callbacks.VOEReportCallback``): VOE statistics of the
validation probes over training (``probe``), image strips of what the model expected to see
(``expectation_images``), the VOE report of a ``test`` run (``report``), a checkpoint of the final
training step (``final_step_checkpoint``), a resumable checkpoint when a fit is interrupted
(``interruption``) and ``predict``'s submission files (``prediction_writer``)."""

from voe_lightning.callbacks.expectation_images import ExpectationImages
from voe_lightning.callbacks.final_step_checkpoint import FinalStepCheckpoint
from voe_lightning.callbacks.interruption import InterruptCheckpoint
from voe_lightning.callbacks.prediction_writer import IntPhys2LeaderboardWriter, IntPhysAnswerWriter
from voe_lightning.callbacks.probe import VOEProbeCallback, voe_table
from voe_lightning.callbacks.report import VOEReportCallback

__all__ = [
    "VOEProbeCallback",
    "voe_table",
    "ExpectationImages",
    "VOEReportCallback",
    "FinalStepCheckpoint",
    "InterruptCheckpoint",
    "IntPhysAnswerWriter",
    "IntPhys2LeaderboardWriter",
]
