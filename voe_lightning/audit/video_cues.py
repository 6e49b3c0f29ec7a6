"""The physics-blind cues of a video (docs/architecture.md §8): each cue's value per frame and
its score per video, on torch tensors, for the cue audit (``voe_lightning.audit.cues``) and the
cue scorer model (``voe_lightning.model.cue_scorer``) alike. Every score is computed on the
frames after ``manipulation_frame`` (the two videos of a pair are identical up to and including
it), per video, with frames x_t in [0, 1]:

- ``foreground_pixels``: visible object pixels (mask id > 0), summed over frames;
- ``motion_energy``: mean absolute difference of consecutive frames, summed;
- ``copy_last_error``: mean squared error of predicting each frame by the one before;
- ``linear_extrapolation_error``: mean squared error of predicting x_t by
  clip(2 x_{t-1} - x_{t-2}, 0, 1), from t = m + 2 on, so that it reads no frame before m (as
  the other frame-local cues do not: on a quadruplet every one of them gives D = 0 exactly);
- ``pixel_novelty``: per pixel, the L1 distance of its colour to the nearest colour seen at that
  place in any earlier frame, summed (something new appearing where it never was)."""

from __future__ import annotations

import math

import torch

from voe_lightning import specs

__all__ = [
    "CUES",
    "FRAME_LOCAL_CUES",
    "MASK_CUES",
    "counted_frames",
    "frame_scores",
    "frames_after",
    "score_videos",
]

#: The physics-blind scorers, in table order; ``MASK_CUES`` need object masks.
CUES: tuple[str, ...] = (
    "foreground_pixels",
    "motion_energy",
    "copy_last_error",
    "linear_extrapolation_error",
    "pixel_novelty",
)
MASK_CUES: tuple[str, ...] = ("foreground_pixels",)
#: The cues that read each frame on its own; the fairness gate holds them at chance on every
#: pooled row (pixel novelty needs a memory of the video).
FRAME_LOCAL_CUES: tuple[str, ...] = CUES[:4]


def frame_scores(
    frames: torch.Tensor, mask: torch.Tensor | None, first: int = 1
) -> dict[str, torch.Tensor]:
    """Every cue's per-frame value of a batch of videos: uint8 frames [B, T, H, W, 3], mask
    [B, T, H, W] (or None: ``foreground_pixels`` is NaN); float64 [B, T] per cue. Frame t's
    value reads frames up to t only (0 where a cue needs earlier frames); ``pixel_novelty`` is
    computed from frame ``first`` on (0 before), as the frames before it are not scored."""
    if frames.ndim != 5 or frames.shape[-1] != 3:
        raise ValueError(f"frames must be [B, T, H, W, 3], got {tuple(frames.shape)}")
    batch, num_frames = frames.shape[:2]
    x = specs.to_model_input(frames).contiguous()  # [B, T, 3, H, W]: ~10x faster than NHWC

    def per_frame(values: torch.Tensor) -> torch.Tensor:
        """Values of the last frames [B, T - k] as [B, T], 0 for the first k frames."""
        padded = torch.zeros(batch, num_frames, dtype=torch.float64, device=frames.device)
        padded[:, num_frames - values.shape[1] :] = values.double()
        return padded

    difference = x[:, 1:] - x[:, :-1]
    predicted = (2.0 * x[:, 1:-1] - x[:, :-2]).clamp_(0.0, 1.0)
    novelty = torch.zeros(batch, num_frames, dtype=torch.float64, device=frames.device)
    for t in range(max(first, 1), num_frames):
        nearest = (x[:, 0] - x[:, t]).abs_().sum(dim=1)  # [B, H, W], L1 over channels
        for s in range(1, t):
            nearest = torch.minimum(nearest, (x[:, s] - x[:, t]).abs_().sum(dim=1))
        novelty[:, t] = nearest.sum(dim=(1, 2)).double()
    scores = {
        "motion_energy": per_frame(difference.abs().mean(dim=(2, 3, 4))),
        "copy_last_error": per_frame(difference.square().mean(dim=(2, 3, 4))),
        "linear_extrapolation_error": per_frame(
            (x[:, 2:] - predicted).square().mean(dim=(2, 3, 4))
        ),
        "pixel_novelty": novelty,
        "foreground_pixels": (
            torch.full((batch, num_frames), math.nan, dtype=torch.float64, device=frames.device)
            if mask is None
            else (mask > 0).sum(dim=(2, 3)).double()
        ),
    }
    return {cue: scores[cue] for cue in CUES}


#: Frames past m + 1 from which a cue is counted: linear extrapolation predicts frame t from
#: t - 1 and t - 2, so it counts from m + 2 on and, like every frame-local cue, reads no frame
#: before m (a quadruplet's videos differ there, docs/stimuli.md). Pixel novelty alone
#: remembers the frames before m, by design.
_LATER = {"linear_extrapolation_error": 1}


def counted_frames(cue: str, manipulation_frame: torch.Tensor, num_frames: int) -> torch.Tensor:
    """[B, T] bool: the frames whose values ``score_videos`` sums for ``cue``: t > m, and for
    linear extrapolation t > m + 1 (``_LATER``)."""
    return frames_after(manipulation_frame + _LATER.get(cue, 0), num_frames)


def frames_after(manipulation_frame: torch.Tensor, num_frames: int) -> torch.Tensor:
    """[B, T] bool: the frames after each pair's manipulation frame (on its device), the only
    ones the audit scores: both videos are identical up to and including it."""
    m = manipulation_frame.reshape(-1, 1)
    return torch.arange(num_frames, device=m.device)[None] > m


def score_videos(
    frames: torch.Tensor, mask: torch.Tensor | None, manipulation_frame: torch.Tensor
) -> dict[str, torch.Tensor]:
    """Every cue's score of a batch of videos: uint8 frames [B, T, H, W, 3], mask [B, T, H, W]
    (or None: no ``foreground_pixels``, NaN), manipulation frame [B]; float64 [B] per cue.
    Runs on the frames' device; each score sums the per-frame values (``frame_scores``) over
    the frames t > m (linear extrapolation: t > m + 1, ``counted_frames``)."""
    if frames.ndim != 5 or frames.shape[-1] != 3:
        raise ValueError(f"frames must be [B, T, H, W, 3], got {tuple(frames.shape)}")
    batch, num_frames = frames.shape[:2]
    m = torch.as_tensor(manipulation_frame, device=frames.device).reshape(-1).long()
    if m.numel() != batch or bool(((m < 0) | (m >= num_frames)).any()):
        raise ValueError(
            f"manipulation_frame must hold {batch} values in [0, {num_frames - 1}], "
            f"got {m.tolist()}"
        )
    per_frame = frame_scores(frames, mask, first=int(m.min()) + 1)
    return {
        cue: (values * counted_frames(cue, m, num_frames)).sum(dim=1)
        for cue, values in per_frame.items()
    }
