"""Adam with the learning-rate schedules the model families share: ``constant`` (the paper's)
or ``cosine`` (decays to 0 at ``trainer.max_steps``, so the weights settle instead of ending
wherever the last steps left them), after an optional linear warm-up (for large batches)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from lightning.pytorch.utilities.types import OptimizerConfig, OptimizerLRSchedulerConfig

LR_SCHEDULES = ("constant", "cosine")


def check_schedule(lr_schedule: str, warmup_steps: int = 0) -> None:
    """Refuse an unknown schedule, naming the valid ones, or a negative warm-up."""
    if lr_schedule not in LR_SCHEDULES:
        raise ValueError(
            f"unknown lr_schedule {lr_schedule!r}; valid choices are: {', '.join(LR_SCHEDULES)}"
        )
    if warmup_steps < 0:
        raise ValueError(f"lr_warmup_steps must be >= 0, got {warmup_steps}")


def adam(
    parameters: Iterable[torch.nn.Parameter],
    learning_rate: float,
    lr_schedule: str,
    max_steps: int | None,
    betas: tuple[float, float] = (0.9, 0.999),
    warmup_steps: int = 0,
    fused: bool = False,
) -> OptimizerConfig | OptimizerLRSchedulerConfig:
    """Lightning's ``configure_optimizers`` value: Adam, and a per-step scheduler for
    ``cosine`` (from ``learning_rate`` to 0 at ``max_steps``) or a warm-up (the rate rises
    linearly over ``warmup_steps``). ``fused``: one fused kernel per step and the rate a tensor
    on the parameters' device, read there, so neither the step nor a schedule syncs the host."""
    parameters = list(parameters)
    if fused:
        device_rate = torch.tensor(learning_rate, device=parameters[0].device)
        optimizer = torch.optim.Adam(parameters, lr=device_rate, betas=betas, fused=True)
    else:
        optimizer = torch.optim.Adam(parameters, lr=learning_rate, betas=betas)
    if lr_schedule == "constant" and not warmup_steps:
        return {"optimizer": optimizer}
    if lr_schedule == "cosine" and (max_steps is None or max_steps < 1):
        raise ValueError(
            "lr_schedule 'cosine' decays to 0 at trainer.max_steps; set it "
            f"(got max_steps={max_steps})"
        )

    def rate(step: int) -> float:
        warm = min(1.0, (step + 1) / warmup_steps) if warmup_steps else 1.0
        if lr_schedule == "constant":
            return warm
        assert max_steps is not None  # refused above for cosine
        return warm * 0.5 * (1 + math.cos(math.pi * min(step, max_steps) / max_steps))

    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, rate)
    return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}
