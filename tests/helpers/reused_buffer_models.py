"""Surprise callables for ``CallableModel`` (``--model.init_args.function
helpers.reused_buffer_models.NAME``): a causal frame-change score and a future-reading one, each
fresh and written into one reused output buffer, and a frame-local score in bf16 and float32."""

import numpy as np
import torch

#: The one output array every ``*_into_buffer`` call writes into and returns a view of, as a
#: model that preallocates its output does (larger than any batch [B, T] here).
BUFFER = np.zeros((64, 64), dtype=np.float32)


def _into_buffer(surprise: torch.Tensor) -> np.ndarray:
    """``surprise`` [B, T] written into ``BUFFER``, returned as a view of it."""
    view = BUFFER[: surprise.shape[0], : surprise.shape[1]]
    view[...] = surprise.numpy()
    return view


def _brightness(frames: torch.Tensor) -> torch.Tensor:
    return frames.float().mean(dim=(2, 3, 4))


def frame_change(frames: torch.Tensor) -> torch.Tensor:
    """Frame t's mean absolute change from frame t - 1 (0 at frame 0): causal, a fresh tensor."""
    change = (frames[:, 1:].float() - frames[:, :-1].float()).abs().mean(dim=(2, 3, 4))
    return torch.cat([torch.zeros(len(frames), 1), change], dim=1)


def frame_change_into_buffer(frames: torch.Tensor) -> np.ndarray:
    """``frame_change``, returned as a view of the reused ``BUFFER``."""
    return _into_buffer(frame_change(frames))


def next_brightness(frames: torch.Tensor) -> torch.Tensor:
    """Frame t's surprise is frame t + 1's brightness: it reads the future."""
    brightness = _brightness(frames)
    return torch.cat([brightness[:, 1:], brightness[:, -1:]], dim=1)


def next_brightness_into_buffer(frames: torch.Tensor) -> np.ndarray:
    """``next_brightness``, returned as a view of the reused ``BUFFER``."""
    return _into_buffer(next_brightness(frames))


def brightness_bf16(frames: torch.Tensor) -> torch.Tensor:
    """Each frame's own brightness (frame-local: a quadruplet's D is 0), scaled so that bf16
    rounds its sums, in bf16."""
    return (_brightness(frames) * 37.3).to(torch.bfloat16)


def brightness_bf16_as_float32(frames: torch.Tensor) -> torch.Tensor:
    """``brightness_bf16``'s values, exactly, in float32."""
    return brightness_bf16(frames).float()
