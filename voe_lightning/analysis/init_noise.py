"""Noise that draws a model's untrained initializations apart: a family whose every seed builds
one function (predicting heads started at zero) gets, per seed, Gaussian noise on each learned
tensor at the scale of its initialization, so its untrained null tests something
(``analysis.null``)."""

from __future__ import annotations

import math
from typing import cast

import numpy as np
import torch


class NothingToNoise(ValueError):
    """Noise asked of a model with no learned parameter (a follower): it cannot differ."""


#: ``--noise``'s rule, one line (the table's and docs'; ``noise_unit`` says why).
NOISE_RULE = (
    "each learned tensor gets Gaussian noise of sd = noise x the tensor's own sd over its "
    "elements, or, where that is 0 (a head started at zero), x 1/sqrt(3 fan-in), the sd of "
    "PyTorch's default initialization of its layer"
)
#: The noise a null whose plain draws are one function is drawn again with.
NOISE_ADVICE = 1.0
#: Mixed with an initialization's seed into its noise's seed: a stream of its own, not the one
#: ``seed_everything`` drew the initialization from (the same seed would tie the noise to it).
NOISE_STREAM = 0x6E6F697365


def noise_unit(module: torch.nn.Module, parameter: torch.Tensor) -> float:
    """The noise's sd per unit of ``--noise`` on a learned ``parameter`` of ``module``
    (``NOISE_RULE``): the tensor's own sd over its elements, so that noise 1 is a second
    draw's worth of spread on top of the first, whatever the layer's initialization scheme;
    where that sd is 0 (a head started at zero, a bias or a norm's scale that starts
    constant, a lone scalar), 1/sqrt(3 fan-in), the sd of what ``nn.Linear`` and ``nn.Conv``
    draw by default (uniform within 1/sqrt(fan-in)): a zeroed layer's draws then differ by
    as much as a drawn layer's would, not by an arbitrary absolute amount. The fan-in is
    the weight's (input width times kernel size); a bias or a scale takes its module's
    weight's where it has one, else its own length."""
    own = float(parameter.detach().double().std(correction=0)) if parameter.numel() else 0.0
    if own > 0:
        return own
    weight = parameter if parameter.dim() >= 2 else getattr(module, "weight", None)
    layered = isinstance(weight, torch.Tensor) and weight.dim() >= 2
    fan_in = cast(torch.Tensor, weight)[0].numel() if layered else parameter.numel()
    return 1 / math.sqrt(3 * max(fan_in, 1))


def add_noise(model: torch.nn.Module, noise: float, seed: int) -> int:
    """Add Gaussian noise of sd ``noise`` x ``noise_unit`` to every floating-point parameter
    of ``model`` that training would learn (``requires_grad``: a frozen pretrained part or
    any given tensor is kept), in place, drawn from a generator seeded by the
    initialization's ``seed`` (its own stream, ``NOISE_STREAM``): the same seed and noise
    give the same model, and a different seed a different function even where every seed
    builds the same one. Returns how many tensors it changed."""
    stream = np.random.SeedSequence([NOISE_STREAM, seed]).generate_state(1, np.uint64)[0]
    generator = torch.Generator().manual_seed(int(stream))
    seen: set[int] = set()
    with torch.no_grad():
        for module in model.modules():
            for parameter in module.parameters(recurse=False):
                learned = parameter.requires_grad and parameter.is_floating_point()
                if not learned or id(parameter) in seen:
                    continue
                seen.add(id(parameter))
                sd = noise * noise_unit(module, parameter)
                draw = torch.randn(parameter.shape, generator=generator, dtype=torch.float64)
                parameter.add_((sd * draw).to(parameter.device, parameter.dtype))
    return len(seen)
