"""A few optimiser steps of a model on one batch, for the tests that check it learns."""

import torch


def losses_over_steps(model, batch, steps: int, lr: float = 3e-3) -> list[float]:
    """The training loss at each of ``steps`` Adam steps on ``batch`` (``training_step``)."""
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    losses = []
    for step in range(steps):
        optimizer.zero_grad()
        loss = model.training_step(batch, step)
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    return losses
