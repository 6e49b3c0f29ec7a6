"""Which frames a video's surprise is summed over for the statistics: all of them (the paper's,
docs/architecture.md §8) or a window of ``frames`` frames from the pair's first difference, the
first frame at which its two videos differ. A window counts the moment of a violation rather
than every frame of a lasting difference (a plank ending flat rather than propped); it is
reported beside the paper's sums, never instead of them
(docs/study/object_centric_surprise.md)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

#: The window's one start so far: the pair's first difference.
FIRST_DIFFERENCE = "first_difference"
#: How a config names the paper's window.
ALL = "all"


@dataclass(frozen=True)
class SurpriseWindow:
    """``frames`` frames from each pair's first difference; None: all frames."""

    frames: int | None = None

    def __post_init__(self) -> None:
        if self.frames is not None and (
            isinstance(self.frames, bool) or not isinstance(self.frames, int) or self.frames < 1
        ):
            raise ValueError(
                f"a surprise window's frames must be an integer >= 1, got {self.frames!r}"
            )

    @property
    def all_frames(self) -> bool:
        return self.frames is None

    def describe(self) -> str:
        """What the window is, in words, for reports."""
        if self.all_frames:
            return "all frames"
        assert self.frames is not None  # not all_frames
        plural = "s" if self.frames > 1 else ""
        return f"{self.frames} frame{plural} from the pair's first difference"

    def as_config(self) -> str | dict[str, Any]:
        """The window as a config gives it (``surprise_window``)."""
        return ALL if self.all_frames else {"start": FIRST_DIFFERENCE, "frames": self.frames}

    def frame_weights(self, num_frames: int, first_difference: Any) -> np.ndarray:
        """1.0 for the frames of each pair inside the window, else 0.0: [N, num_frames] for
        ``first_difference`` [N] (frame indices; ``num_frames`` when the videos never differ,
        so the window is empty)."""
        start = np.asarray(first_difference, dtype=np.int64).reshape(-1, 1)
        frame = np.arange(num_frames)[None]
        if self.all_frames:
            return np.ones((start.shape[0], num_frames))
        assert self.frames is not None  # not all_frames
        return ((frame >= start) & (frame < start + self.frames)).astype(np.float64)


def video_surprise(
    per_frame: Any, window: SurpriseWindow = SurpriseWindow(), first_difference: Any = None
) -> Any:
    """Each video's surprise from its per-frame surprise [..., T] (a tensor or an array): the
    sum over its frames (the paper's, docs/architecture.md §7), or over ``window``'s frames
    counted from each pair's ``first_difference`` [N] (needed then). The one place a video's
    surprise is made: summed in float64 (a tensor's on its device, or the CPU for Apple's GPUs),
    so neither a model's bf16/fp16 rounding nor a float32 overflow enters the statistics; a sum
    of finite per-frame surprise that still overflows is a ValueError saying so (``_check_no_overflow``)."""
    if isinstance(per_frame, torch.Tensor):
        if per_frame.device.type == "mps":  # Apple's GPUs have no float64
            per_frame = per_frame.cpu()
        per_frame = per_frame.double()
    else:
        per_frame = np.asarray(per_frame, dtype=np.float64)
    if not window.all_frames:
        if first_difference is None:
            raise ValueError(
                f"a surprise window of {window.describe()} needs each pair's first difference"
            )
        first = (
            first_difference.cpu()
            if isinstance(first_difference, torch.Tensor)
            else first_difference
        )
        weights: np.ndarray | torch.Tensor = window.frame_weights(per_frame.shape[-1], first)
        if isinstance(per_frame, torch.Tensor):
            weights = torch.as_tensor(weights, dtype=per_frame.dtype, device=per_frame.device)
        per_frame = per_frame * weights
    with np.errstate(over="ignore"):  # an overflow is named below, not warned about
        return _check_no_overflow(per_frame, per_frame.sum(-1))


def _check_no_overflow(per_frame: Any, sums: Any) -> Any:
    """``sums`` of ``per_frame`` surprise, unless a sum is infinite while every per-frame value
    is finite: a ValueError naming the overflow, which is the sum's, not the model's."""
    module = torch if isinstance(sums, torch.Tensor) else np
    if bool(module.isfinite(sums).all()) or not bool(module.isfinite(per_frame).all()):
        return sums
    largest = float(abs(per_frame).max())
    raise ValueError(
        f"a video's surprise, the sum of its per-frame surprise, overflows float64: every "
        f"per-frame value is finite (up to {largest:.3g} in size) but their sum is not; "
        "scale the model's surprise down (e.g. in nats or bits rather than raw likelihoods)"
    )


def surprise_window(value: Any) -> SurpriseWindow:
    """A window from what a config gives: ``all`` (or None), ``{start: first_difference,
    frames: k}``, or a ``SurpriseWindow``; anything else is refused naming what is valid."""
    if isinstance(value, SurpriseWindow):
        return value
    if value is None or value == ALL:
        return SurpriseWindow()
    valid = f"valid: '{ALL}' (the paper's) or {{start: {FIRST_DIFFERENCE}, frames: k}} with k >= 1"
    if not isinstance(value, Mapping):
        raise ValueError(f"surprise_window {value!r} is not a window; {valid}")
    if set(value) != {"start", "frames"} or value["start"] != FIRST_DIFFERENCE:
        raise ValueError(f"surprise_window {dict(value)!r} is not a window; {valid}")
    try:
        return SurpriseWindow(value["frames"])
    except ValueError as error:
        raise ValueError(f"surprise_window {dict(value)!r}: {error}; {valid}") from None


def first_difference(consistent: torch.Tensor, inconsistent: torch.Tensor) -> torch.Tensor:
    """The first frame at which each pair's two videos differ, int64 [B], from their frames
    [B, T, ...]; T where they never do."""
    differs = (consistent != inconsistent).flatten(2).any(-1)  # [B, T]
    steps = differs.shape[1]
    frame = torch.arange(steps, device=differs.device)
    return torch.where(differs, frame, steps).min(dim=1).values
