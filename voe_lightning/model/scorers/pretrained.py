"""What the package's wrappers of a maintained library's pretrained video model share
(``VideoMAEScorer``, ``VJEPA2Scorer``): Hugging Face transformers imported with a clear error,
the network loaded from a local folder (never the network) or built at random from a config
(tests), frozen in eval mode, ImageNet-normalized input, and surprise with its running total as
the trajectory."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase

from voe_lightning.model.base import SurpriseModel

#: The normalization these models' inputs carry (transformers' IMAGENET_DEFAULT_MEAN / _STD).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def transformers_module(scorer: str, extra: str, version: str) -> Any:
    """Hugging Face transformers, or an ImportError naming the install for ``scorer``."""
    try:
        import transformers
    except ImportError:
        raise ImportError(
            f"{scorer} needs Hugging Face transformers: pip install "
            f"'voe_lightning[{extra}]' (or transformers>={version})"
        ) from None
    return transformers


class PretrainedScorer(SurpriseModel):
    """A frozen transformers network as a ``SurpriseModel``: ``self.model`` is loaded from the
    local folder ``pretrained`` or built from ``config`` arguments (exactly one of the two), in
    eval mode with no gradients; ``normalized`` maps [0, 1] input to the ImageNet statistics.
    Subclasses implement ``surprise`` and ``expected_frames``."""

    #: The ImageNet statistics as buffers [1, 1, 3, 1, 1] (registered in ``__init__``).
    mean: torch.Tensor
    std: torch.Tensor

    def __init__(
        self,
        model_class: Any,
        config_class: Any,
        pretrained: str | None,
        config: dict[str, Any] | None,
    ):
        super().__init__()
        name = type(self).__name__
        if (pretrained is None) == (config is None):
            raise ValueError(
                f"give {name} either pretrained (a local folder) or config "
                f"({config_class.__name__} arguments), got pretrained="
                f"{pretrained!r}, config={config!r}"
            )
        if pretrained is not None:
            self.model = model_class.from_pretrained(pretrained, local_files_only=True)
        else:
            assert config is not None  # exactly one of the two, checked above
            self.model = model_class(config_class(**config))
        self.model.eval().requires_grad_(False)
        self.register_buffer(
            "mean", torch.tensor(IMAGENET_MEAN)[None, None, :, None, None], persistent=False
        )
        self.register_buffer(
            "std", torch.tensor(IMAGENET_STD)[None, None, :, None, None], persistent=False
        )

    def inputs_read(self) -> frozenset[str]:
        """A pretrained video model sees the frames only."""
        return frozenset()

    def train(self, mode: bool = True) -> PretrainedScorer:
        """Stays in eval mode (no dropout): a frozen scorer."""
        return super().train(False)

    def normalized(self, x: torch.Tensor) -> torch.Tensor:
        """[B, T, 3, H, W] in [0, 1] -> the network's ImageNet-normalized input."""
        return (x - self.mean) / self.std

    def trajectories(
        self,
        frames: torch.Tensor,
        mask: torch.Tensor | None = None,
        camera: torch.Tensor | None = None,
        objects: TensorDictBase | None = None,
    ) -> dict[str, torch.Tensor]:
        """Surprise and its running total, a course [B, T, 2]."""
        value = self.surprise(frames)
        return {"surprise": torch.stack([value, value.cumsum(dim=1)], dim=-1)}
