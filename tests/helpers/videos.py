"""Synthetic videos the model tests train and score on."""

import torch


def moving_squares(batch: int, seed: int, frames: int = 5, size: int = 32) -> torch.Tensor:
    """uint8 videos [batch, frames, size, size, 3] of a bright square moving right at a random
    speed on a dark background."""
    generator = torch.Generator().manual_seed(seed)
    video = torch.zeros(batch, frames, size, size, 3, dtype=torch.uint8)
    start = torch.randint(0, 8, (batch,), generator=generator)
    speed = torch.randint(1, 5, (batch,), generator=generator)
    for b in range(batch):
        for t in range(frames):
            x = int(start[b] + speed[b] * t)
            video[b, t, 10:18, x : x + 8] = 255
    return video
