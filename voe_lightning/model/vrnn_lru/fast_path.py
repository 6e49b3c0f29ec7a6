"""The VRNN-LRU's fast path, which speeds it without changing its maps: the precisions its
encoder and decoder may run in (``PRECISIONS``; bf16 where ``bf16_is_fast``) and whether they
and the recurrent core's step are compiled (``COMPILE_MODES``)."""

from __future__ import annotations

import torch

PRECISIONS = ("auto", "bf16", "float32")
#: ``compile``: ``frame`` compiles the recurrent core's step and the encoder and decoder;
#: ``auto`` does so on a GPU only (on a CPU compiling costs about a minute).
COMPILE_MODES = ("auto", "off", "frame")


def bf16_is_fast(device: torch.device) -> bool:
    """Whether ``device`` runs bf16 convolutions natively: a CUDA GPU that supports bf16, or a
    CPU with AVX512-BF16 or AMX (elsewhere oneDNN emulates bf16, several times slower)."""
    if device.type == "cuda":
        supported: bool = torch.cuda.is_bf16_supported()
        return supported
    if device.type == "cpu":
        native: bool = torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported()
        return native
    return False
