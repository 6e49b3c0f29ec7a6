"""Adam with the learning-rate schedules the model families share: ``constant`` (the paper's)
or ``cosine`` (decays to 0 at ``trainer.max_steps``, so the weights settle instead of ending
wherever the last steps left them)."""

from __future__ import annotations

import math
from collections.abc import Iterable

import torch

LR_SCHEDULES = ("constant", "cosine")


def check_schedule(lr_schedule: str) -> None:
    """Refuse an unknown schedule, naming the valid ones."""
    if lr_schedule not in LR_SCHEDULES:
        raise ValueError(f"unknown lr_schedule {lr_schedule!r}; valid choices are: "
                         f"{', '.join(LR_SCHEDULES)}")


def adam(parameters: Iterable[torch.nn.Parameter], learning_rate: float, lr_schedule: str,
         max_steps: int | None, betas: tuple[float, float] = (0.9, 0.999)) -> dict:
    """Lightning's ``configure_optimizers`` value: Adam, and for ``cosine`` a per-step
    scheduler that decays the rate from ``learning_rate`` to 0 at ``max_steps``."""
    optimizer = torch.optim.Adam(parameters, lr=learning_rate, betas=betas)
    if lr_schedule == "constant":
        return {"optimizer": optimizer}
    if max_steps is None or max_steps < 1:
        raise ValueError("lr_schedule 'cosine' decays to 0 at trainer.max_steps; set it "
                         f"(got max_steps={max_steps})")
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: 0.5 * (1 + math.cos(math.pi * min(step, max_steps) / max_steps))
    )
    return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}
