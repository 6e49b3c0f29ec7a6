"""The object-centric model's networks, built from its arguments (``build_networks``), and the
code size at which its object-free twin has as many parameters (``matching_code_size``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import nn

from voe_lightning.model.dynamics import SlotDynamics
from voe_lightning.model.object_centric.perception import Perception


def build_networks(hparams: Mapping[str, Any], code_size: int) -> tuple[Perception, SlotDynamics]:
    """The perception and dynamics networks for the model's arguments and ``code_size``."""
    perception = Perception(
        hparams["image_size"],
        code_size,
        hparams["encoder_channels"],
        hparams["variational"],
        hparams["channels_last"],
    )
    dynamics = SlotDynamics(
        code_size,
        hparams["state_size"],
        hparams["relation_sizes"],
        hparams["node_sizes"],
        hparams["relation_size"],
        interactions=not hparams["object_free"],
        use_camera=hparams["use_camera"],
        visibility=hparams["surprise"] == "likelihood",
        min_std=hparams["min_code_std"],
    )
    return perception, dynamics


def parameter_count(modules: Sequence[nn.Module]) -> int:
    """Number of parameters of ``modules``."""
    return sum(p.numel() for module in modules for p in module.parameters())


def matching_code_size(hparams: Mapping[str, Any]) -> int:
    """The object-free twin's code size whose parameter count is closest to that of the
    object-centric model with the same arguments (built on the meta device: no memory)."""
    code_size: int = hparams["code_size"]
    with torch.device("meta"):
        target = parameter_count(build_networks({**hparams, "object_free": False}, code_size))

        def count(size: int) -> int:
            return parameter_count(build_networks(hparams, size))

        low, high = 1, 2 * code_size
        while count(high) < target:
            high *= 2
        while high - low > 1:  # the count grows with the code size
            middle = (low + high) // 2
            low, high = (middle, high) if count(middle) < target else (low, middle)
        return min((low, high), key=lambda size: abs(count(size) - target))
