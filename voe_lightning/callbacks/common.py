"""What the callbacks share: the run's significance level, what a probe callback found
(``ProbeOutcome``), the probe DataModule's concept and variant names, a probe batch's surprise
checked finite, and objects gathered from every DDP rank."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import torch

from voe_lightning.probe_datamodule import probe_datamodule
from voe_lightning.stats.causality import Causality
from voe_lightning.stats.statistics import check_alpha

#: The two videos of a probe pair, as ``probe_step`` names their surprise (``surprise_<side>``).
SIDES = ("consistent", "inconsistent")


class RunAlpha:
    """A callback's ``alpha``: the run's significance level, which the CLI hands every callback
    that takes one (configs/base.yaml's ``alpha``); a callback used without it refuses to test
    rather than fall back on a default."""

    def __init__(self, alpha: float | None) -> None:
        self._alpha = None if alpha is None else check_alpha(alpha)

    @property
    def alpha(self) -> float:
        if self._alpha is None:
            raise ValueError(
                f"{type(self).__name__} was given no alpha: pass the run's significance level "
                "(alpha=0.01 is configs/base.yaml's; the CLI hands it over)"
            )
        return self._alpha


@dataclass(frozen=True)
class ProbeOutcome:
    """What a probe callback found on its last run, for the CLI: its causality check (None
    before one ran) and the report folder it wrote (None for none)."""

    causality: Causality | None
    report_dir: Path | None = None


def probe_names(trainer: L.Trainer, user: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The DataModule's concept and variant names (refused unless it is a ProbeDataModule)."""
    datamodule = probe_datamodule(trainer, user)
    return tuple(datamodule.concept_names), tuple(datamodule.variant_names)


def check_finite_surprise(
    outputs: Mapping[str, Any], concept_names: Sequence[str], variant_names: Sequence[str]
) -> None:
    """Refuse a probe batch (``probe_step``'s outputs) whose per-frame surprise holds NaN or an
    infinity, naming the first such frame by concept, variant, seed, video and frame index (no
    statistic can use it, and a count of pairs leaves the user to find it)."""
    sides = {side: torch.as_tensor(outputs[f"surprise_{side}"]) for side in SIDES}
    bad = {side: ~torch.isfinite(surprise) for side, surprise in sides.items()}
    count = sum(int(frames.sum()) for frames in bad.values())
    total = sum(frames.numel() for frames in bad.values())
    side = next((side for side in SIDES if bad[side].any()), None)
    if side is None:
        return
    pair, frame = (int(index) for index in bad[side].nonzero()[0])
    concept = concept_names[int(outputs["concept"][pair])]
    variant = variant_names[int(outputs["variant"][pair])]
    seed = f" seed {int(outputs['seed'][pair])}" if "seed" in outputs else ""
    raise ValueError(
        f"the model's surprise is {float(sides[side][pair, frame])} at frame {frame} of the "
        f"{side} video of {concept} {variant}{seed} ({count} of the batch's {total} per-frame "
        "values are NaN or infinite); surprise must be a finite number at every frame"
    )


def gather_objects(value: Any) -> list[Any]:
    """All ranks' values under torch.distributed (DDP test), else [value]."""
    import torch.distributed as dist

    if dist.is_available() and dist.is_initialized() and dist.get_world_size() > 1:
        gathered: list[Any] = [None] * dist.get_world_size()
        dist.all_gather_object(gathered, value)
        return gathered
    return [value]
