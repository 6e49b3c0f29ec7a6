"""Physics-blind baselines as a model family: one frame-local cue of ``voe_lightning.audit.video_cues`` as
a parameter-free ``SurpriseModel``, so ``test`` and ``predict`` score it like any model, with no
checkpoint, on our probes and on every benchmark, and its rows stand beside a model's."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from voe_lightning import specs
from voe_lightning.audit import video_cues
from voe_lightning.model.base import SurpriseModel

#: Short names of ``CueScorer``'s cues (``video_cues.CUES``' names are accepted too).
CUE_NAMES: dict[str, str] = {
    "foreground": "foreground_pixels",
    "motion": "motion_energy",
    "copy_last": "copy_last_error",
    "linear_extrapolation": "linear_extrapolation_error",
    "novelty": "pixel_novelty",
}


class CueScorer(SurpriseModel):
    """Per-frame surprise = a physics-blind cue's value at that frame (``video_cues.frame_scores``:
    frame t's value reads frames up to t only): ``motion`` (mean absolute difference to the
    previous frame), ``copy_last`` (its squared error), ``linear_extrapolation`` (squared error
    of clip(2 x_{t-1} - x_{t-2})), ``novelty`` (colour distance to the nearest colour seen at
    each place before) or ``foreground`` (visible object pixels: needs masks, which the
    benchmarks do not have). It has no parameters, so it needs no checkpoint and cannot be
    trained (``fit`` has nothing to optimize).

    Args:
        cue: one of motion, copy_last, linear_extrapolation, novelty, foreground.
    """

    SURPRISE = "a physics-blind cue"

    def __init__(self, cue: str = "motion"):
        super().__init__()
        if cue not in CUE_NAMES and cue not in CUE_NAMES.values():
            raise ValueError(f"unknown cue {cue!r}; valid cues are: {', '.join(CUE_NAMES)}")
        self.save_hyperparameters()
        self.cue_name = CUE_NAMES.get(cue, cue)

    def setup(self, stage: str) -> None:
        """Refuse a mask cue on data without masks (``ProbeDataModule.without_masks``: IntPhys,
        IntPhys 2), whose zero masks would score 0 everywhere, before any batch."""
        super().setup(stage)
        data = getattr(self._trainer, "datamodule", None)
        benchmark = getattr(data, "without_masks", None)
        if self.cue_name in video_cues.MASK_CUES and benchmark:
            raise ValueError(
                f"CueScorer cue {self.hparams['cue']!r} counts object pixels in the masks, and "
                f"{benchmark} has no masks (its videos' masks would all be zero): choose "
                f"one of {', '.join(self._frame_cues())}"
            )

    @staticmethod
    def _frame_cues() -> list[str]:
        """The cues that read frames only (no masks)."""
        return [name for name, cue in CUE_NAMES.items() if cue not in video_cues.MASK_CUES]

    def inputs_read(self) -> frozenset[str]:
        """A mask cue reads the masks, a frame cue the frames only."""
        return frozenset({"mask"} if self.cue_name in video_cues.MASK_CUES else ())

    def surprise(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        if self.cue_name in video_cues.MASK_CUES and mask is None:
            raise ValueError(
                f"cue {self.hparams['cue']!r} counts object pixels and needs masks; "
                f"this data has none: choose one of {', '.join(self._frame_cues())}"
            )
        return video_cues.frame_scores(frames, mask)[self.cue_name].float()

    def expected_frames(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> torch.Tensor:
        """The frame the cue compares frame t with: the linear extrapolation of the two before
        it for ``linear_extrapolation``, else the previous frame (frame 0: itself)."""
        x = specs.to_model_input(frames)
        previous = torch.cat([x[:, :1], x[:, :-1]], dim=1)
        if self.cue_name != "linear_extrapolation_error":
            return previous
        before = torch.cat([previous[:, :1], previous[:, :-1]], dim=1)
        return (2.0 * previous - before).clamp(0.0, 1.0)

    def trajectories(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> dict[str, torch.Tensor]:
        """The cue's per-frame value and its running total, a course [B, T, 2] (the report's
        t-SNE figure projects courses onto two components)."""
        value = self.surprise(frames, mask)
        return {"cue": torch.stack([value, value.cumsum(dim=1)], dim=-1)}
