"""A screen lowered in front of a scene and raised again (unchangeableness's occluder): a thin
wooden box, its smooth down-hold-up motion scaled to the video, drawn to start just out of view
above; a mocap body that a per-frame script moves."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from voe_lightning.scenes.builder import SceneBuilder
from voe_lightning.scenes.camera import CameraPose, VideoOptions, height_above_view
from voe_lightning.scenes.simulation import Simulation

#: Depth of the screen's box (m).
SCREEN_THICKNESS = 0.04
#: Wooden screen tone; each screen scales it a little so it never matches an object colour.
SCREEN_COLOR = (0.52, 0.38, 0.24)


@dataclass
class ScreenMotion:
    """A screen lowered from ``top`` (its bottom edge's height) to ``bottom`` over frames
    [start, down], held, and raised back over [up, end] with smooth cosine easing."""

    top: float
    bottom: float
    start: float
    down: float
    up: float
    end: float

    def bottom_height(self, frame: float) -> float:
        """The bottom edge's height at ``frame`` (fractional frames allowed)."""
        if frame <= self.start or frame >= self.end:
            progress = 0.0
        elif frame < self.down:
            progress = 0.5 - 0.5 * math.cos(
                math.pi * (frame - self.start) / (self.down - self.start)
            )
        elif frame <= self.up:
            progress = 1.0
        else:
            progress = 0.5 + 0.5 * math.cos(math.pi * (frame - self.up) / (self.end - self.up))
        return self.top + (self.bottom - self.top) * progress

    def hidden_frames(self) -> list[int]:
        """Frames f with the screen fully down at f - 1 and f: when a hidden change can happen."""
        return [f for f in range(1, math.floor(self.up) + 1) if f - 1 >= self.down]


def draw_motion(
    rng: np.random.Generator, video: VideoOptions, top: float, bottom: float
) -> ScreenMotion:
    """Random timing of the lowering and raising, scaled to the video's length."""
    scale = video.num_frames / 15.0
    start = rng.uniform(0.3, 2.0) * scale
    down = start + rng.uniform(3.5, 4.5) * scale
    up = down + rng.uniform(2.0, 3.0) * scale
    end = up + rng.uniform(3.5, 4.5) * scale
    return ScreenMotion(top, bottom, start, down, up, end)


@dataclass
class Screen:
    """A large thin box (mocap) spanning ``width`` x ``height`` at (x, y), moved per frame."""

    x: float
    y: float
    width: float
    height: float
    color: tuple[float, float, float]
    motion: ScreenMotion

    def add_to(self, builder: SceneBuilder) -> None:
        """Add the screen to ``builder`` as a mocap box, placed where it is at frame 0."""
        size = [self.width / 2, SCREEN_THICKNESS / 2, self.height / 2]
        builder.add_primitive(
            "screen", "box", size, self.position(0), self.color, free=False, mocap=True
        )

    def position(self, frame: float) -> tuple[float, float, float]:
        """The screen's centre at ``frame``."""
        return (self.x, self.y, self.motion.bottom_height(frame) + self.height / 2)

    def script(self, sim: Simulation, frame: int) -> None:
        """Per-frame script for Simulation.record / record_pair: place the screen."""
        sim.move("screen", self.position(frame))


def draw_screen_color(rng: np.random.Generator) -> tuple[float, float, float]:
    """SCREEN_COLOR scaled by a random factor, so that no two screens share one tone."""
    red, green, blue = np.clip(np.array(SCREEN_COLOR) * rng.uniform(0.8, 1.25), 0, 1)
    return float(red), float(green), float(blue)


def draw_screen(
    rng: np.random.Generator,
    camera: CameraPose,
    video: VideoOptions,
    x: float,
    y: float,
    width: float,
    height: float,
    bottom: float,
) -> Screen:
    """A screen at (x, y) that starts just out of view above and is lowered to ``bottom``."""
    top = min(height_above_view(camera, x, y), 4.0) + float(rng.uniform(0.05, 0.3))
    return Screen(x, y, width, height, draw_screen_color(rng), draw_motion(rng, video, top, bottom))
