"""What the probe callbacks of a trainer found, read by the CLI as typed outcomes."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from voe_lightning.callbacks.common import ProbeOutcome
from voe_lightning.callbacks.probe import VOEProbeCallback
from voe_lightning.callbacks.report import VOEReportCallback


def probe_outcomes(callbacks: Iterable[Any]) -> list[ProbeOutcome]:
    """The ``ProbeOutcome`` of each probe callback among ``callbacks`` (a trainer's), in order."""
    return [
        callback.outcome
        for callback in callbacks
        if isinstance(callback, (VOEProbeCallback, VOEReportCallback))
    ]


def report_folders(callbacks: Iterable[Any]) -> list[Path]:
    """The report folders the callbacks wrote, in order (none before a test)."""
    return [o.report_dir for o in probe_outcomes(callbacks) if o.report_dir is not None]
