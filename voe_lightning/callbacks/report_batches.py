"""What ``VOEReportCallback`` keeps of each test batch: its ``test_step`` output, the
``probe_step`` dict of per-frame surprise (``ProbeOutputs``), and the physics-blind cues of
its pairs (``CueScores``), so the report's model rows and cue rows share the same pairs."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from voe_lightning.audit import cues
from voe_lightning.report.pairs import (
    FIRST_DIFFERENCE,
    INPUTS_DIFFER,
    PROBE_OUTPUT_KEYS,
    as_numpy,
)


class ProbeOutputs:
    """Each test batch's ``probe_step`` dict, checked and held on the CPU as numpy arrays
    (``kept``, one dict per batch, which ``PairResults.from_probe_outputs`` reads)."""

    def __init__(self) -> None:
        self.kept: list[dict[str, np.ndarray]] = []

    def add(self, outputs: Any) -> dict[str, np.ndarray]:
        """Keep ``outputs`` (``test_step``'s return) and return what was kept; refused unless
        it is the ``probe_step`` dict with every key of ``PROBE_OUTPUT_KEYS``."""
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
            for key in (*PROBE_OUTPUT_KEYS, FIRST_DIFFERENCE, INPUTS_DIFFER)
            if key in outputs
        }
        self.kept.append(stored)
        return stored


class CueScores:
    """The cue audit of each test batch's pairs (``audit.cues.CueAudit.score_batch``, on the
    batch's device), names decoded with the DataModule's ``concept_names`` and
    ``variant_names``, with the followers of the inputs the model reads (``followers``:
    ``states``, ``masks``; ``audit.followers.features_read``)."""

    def __init__(
        self,
        concept_names: Sequence[str],
        variant_names: Sequence[str],
        followers: Sequence[str] = (),
    ) -> None:
        self.concept_names, self.variant_names = concept_names, variant_names
        self.followers = tuple(followers)
        self.kept: list[cues.CueAudit] = []

    def add(self, batch: Any) -> None:
        self.kept.append(
            cues.CueAudit.score_batch(batch, self.concept_names, self.variant_names, self.followers)
        )

    @staticmethod
    def audit(gathered: Iterable[list[cues.CueAudit]]) -> cues.CueAudit:
        """One audit of every rank's ``kept`` scores, in order."""
        return cues.CueAudit.concatenate(audit for rank in gathered for audit in rank)
