"""How a scene is filmed: the video's size and timing (``VideoOptions``), the free camera's pose
(``CameraPose``), each concept's camera distribution (``CameraRange``, the "one world" of
docs/architecture.md §4), and the projection between world points and image pixels that scenes
use to place objects in or out of view. One home for the camera's geometry, so every concept
projects alike (the positive control's ``model/object_geometry.py`` is its torch twin)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from voe_lightning import specs

#: The longest physics step (s): a video made at a frame rate (``VideoOptions.at_fps``) splits
#: each frame period into as many equal steps of at most this as it takes (the paper's 0.01 s,
#: 20 steps a frame at 5 fps).
MAX_TIMESTEP = 0.01
#: The paper's clip length (s): 15 frames at 5 fps, the length every concept's scenes are timed
#: for (``check_duration``).
PAPER_DURATION = 3.0
#: The clip lengths (s) every concept's scenes are drawn in with the paper's motion: continuity's
#: ball crosses the view in the clip at the paper's probe speeds (0.55 to 1.2 m/s), which found
#: draws for every seed tried from 2.2 to 5 s and for none below 1.8 or above 5.5 s (10 seeds of
#: each variant and of the gap_block control); containment's slide and unchangeableness's screen
#: fill the clip, so they move at the paper's pace times 3 s over the duration (two thirds to
#: six fifths of it here). Solidity's and continuity's probes need enough frames
#: (``solidity.check_video``, ``continuity.check_video``).
DURATIONS = (2.5, 4.5)


@dataclass(frozen=True)
class VideoOptions:
    """Geometry and timing of a rendered video (paper: 15 frames, 64x64, about 3 s). Made with
    a frame rate (``at_fps``), frames fall at exact multiples of 1/fps; made without one (the
    default, as every store before ``generate --fps``), the clip is 3 s long and a frame is the
    whole number of 0.01 s steps nearest to 3 s over ``num_frames`` (exactly 0.2 s at 15)."""

    num_frames: int = specs.NUM_FRAMES
    height: int = specs.HEIGHT
    width: int = specs.WIDTH
    duration: float = 3.0
    timestep: float = 0.01

    def __post_init__(self) -> None:
        for name in ("num_frames", "height", "width"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not 0 < self.timestep <= self.duration / self.num_frames:
            raise ValueError(
                f"timestep {self.timestep} must be in (0, duration/num_frames="
                f"{self.duration / self.num_frames:g}]"
            )

    @property
    def steps_per_frame(self) -> int:
        return max(1, round(self.duration / self.num_frames / self.timestep))

    @property
    def fps(self) -> float:
        """Frames per second: ``num_frames`` over ``duration`` (5 for the paper's clips)."""
        return self.num_frames / self.duration

    @classmethod
    def at_fps(
        cls,
        fps: float,
        num_frames: int = specs.NUM_FRAMES,
        height: int = specs.HEIGHT,
        width: int = specs.WIDTH,
    ) -> VideoOptions:
        """``num_frames`` frames at ``fps`` frames per second: a clip of num_frames / fps s
        whose physics step divides the frame period exactly (the period over the fewest equal
        steps of at most ``MAX_TIMESTEP``), so that frame k shows the scene at k / fps s. At 5
        fps and 15 frames these are the default options, field for field."""
        check_fps(fps)
        duration = num_frames / fps
        period = duration / num_frames
        steps = max(1, math.ceil(period / MAX_TIMESTEP - 1e-9))
        return cls(num_frames, height, width, duration, period / steps)


def check_duration(video: VideoOptions) -> None:
    """Refuse a clip whose length (num_frames / fps) lies outside ``DURATIONS``, naming it and
    the frame rate that would give the paper's 3 s at its num_frames."""
    low, high = DURATIONS
    if not low - 1e-9 <= video.duration <= high + 1e-9:
        raise ValueError(
            f"{video.num_frames} frames at {video.fps:g} fps last {video.duration:g} s; the "
            f"scenes are timed for the paper's {PAPER_DURATION:g} s and drawn in {low:g} to "
            f"{high:g} s: give an fps from {video.num_frames / high:g} to "
            f"{video.num_frames / low:g} (e.g. {video.num_frames / PAPER_DURATION:g}) or "
            f"fewer or more frames"
        )


def check_fps(fps: object) -> None:
    """Refuse a frame rate that is not a positive, finite number, naming it."""
    if (
        isinstance(fps, bool)
        or not isinstance(fps, int | float)
        or not math.isfinite(fps)
        or fps <= 0
    ):
        raise ValueError(
            f"fps must be a positive number of frames per second (the paper's is 5: 15 "
            f"frames in 3 s), got {fps!r}"
        )


#: The fewest pixels a side, and the most times wider than tall, of frames every concept's
#: scenes are drawn in (below or beyond, some draws leave an object out of view or the view
#: holds no room for a scene: 4 in 100 scenes failed at 12 x 12, 0 in 300 at 16 x 16; taller
#: than wide, 64 x 48, or 16 x 64 failed).
MIN_SIZE = 16
MAX_ASPECT = 2


def draws_every_scene(video: VideoOptions) -> bool:
    """Whether every concept's scenes are known to be drawn in frames of ``video``'s size:
    ``MIN_SIZE`` pixels or more a side, no taller than wide nor over ``MAX_ASPECT`` times as
    wide (a scene whose objects do not fit the view is drawn again, 50 times at most)."""
    return MIN_SIZE <= video.height <= video.width <= MAX_ASPECT * video.height


def size_advice(video: VideoOptions) -> str:
    """What to say of a scene no draw of which fits ``video``'s frame, outside those sizes."""
    return (
        f"a {video.height} x {video.width} (height x width) frame is too small or narrow to "
        f"draw a valid scene in; use frames of at least {MIN_SIZE} x {MIN_SIZE}, no taller "
        f"than wide nor over {MAX_ASPECT} times as wide (the default is {specs.HEIGHT} x "
        f"{specs.WIDTH})"
    )


def accept_any_video(video: VideoOptions) -> None:
    """The ``check_video`` of a concept whose scenes render videos of any size and length:
    nothing to refuse."""


@dataclass(frozen=True)
class CameraPose:
    """A free camera looking at ``lookat`` from ``distance`` at ``azimuth``/``elevation`` (deg)."""

    lookat: tuple[float, float, float] = (0.0, 0.0, 0.4)
    distance: float = 4.0
    azimuth: float = 90.0
    elevation: float = -20.0

    def as_array(self) -> np.ndarray:
        return np.array([*self.lookat, self.distance, self.azimuth, self.elevation], np.float32)


@dataclass(frozen=True)
class CameraRange:
    """One concept's camera distribution: each pose parameter uniform in its (low, high).
    Examples, every control and the probes of a concept draw from it (docs/architecture.md §4, "one
    world"); probes may draw from a narrower range that lies inside it (``narrow``)."""

    lookat_x: tuple[float, float]
    lookat_y: tuple[float, float]
    lookat_z: tuple[float, float]
    distance: tuple[float, float]
    azimuth: tuple[float, float]
    elevation: tuple[float, float]

    def __post_init__(self) -> None:
        for name, (low, high) in self.ranges().items():
            if not low <= high:
                raise ValueError(f"camera range {name} must have low <= high, got ({low}, {high})")

    def ranges(self) -> dict[str, tuple[float, float]]:
        """The (low, high) of each parameter, in the order of ``CameraPose.as_array``."""
        return {name: getattr(self, name) for name in CAMERA_PARAMETERS}

    def sample(self, rng: np.random.Generator) -> CameraPose:
        x, y, z, distance, azimuth, elevation = (
            float(rng.uniform(low, high)) for low, high in self.ranges().values()
        )
        return CameraPose((x, y, z), distance, azimuth, elevation)

    def contains(self, camera: CameraPose | np.ndarray, tolerance: float = 1e-4) -> bool:
        """Whether a pose (or a ``[..., 6]`` array of poses) lies inside every range."""
        values = np.asarray(camera.as_array() if isinstance(camera, CameraPose) else camera)
        low, high = np.array(list(self.ranges().values()), np.float64).T
        return bool(((values >= low - tolerance) & (values <= high + tolerance)).all())

    def narrow(self, **ranges: tuple[float, float]) -> CameraRange:
        """A sub-range for probes; refuses a range that leaves this one."""
        for name, (low, high) in ranges.items():
            outer_low, outer_high = self.ranges()[name]
            if low < outer_low or high > outer_high:
                raise ValueError(
                    f"probe camera {name} range ({low}, {high}) leaves the training range "
                    f"({outer_low}, {outer_high})"
                )
        return CameraRange(**{**self.ranges(), **ranges})


#: Names of the six camera parameters, in the order of ``CameraPose.as_array``.
CAMERA_PARAMETERS = ("lookat_x", "lookat_y", "lookat_z", "distance", "azimuth", "elevation")

#: Vertical field of view of MuJoCo's free camera (model default, degrees).
FOVY = 45.0


def camera_axes(camera: CameraPose) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Position, right, up and forward unit vectors of MuJoCo's free camera at ``camera``."""
    az, el = math.radians(camera.azimuth), math.radians(camera.elevation)
    forward = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    up = np.array([-math.sin(el) * math.cos(az), -math.sin(el) * math.sin(az), math.cos(el)])
    position = np.asarray(camera.lookat) - camera.distance * forward
    return position, np.cross(forward, up), up, forward


def camera_coordinates(
    camera: CameraPose, point: Sequence[float] | np.ndarray
) -> tuple[float, float, float]:
    """The world ``point`` in the camera's frame: its offsets along right, up and forward
    (depth); every projection of a point into the image starts here."""
    position, right, up, forward = camera_axes(camera)
    offset = np.asarray(point, float) - position
    return offset @ right, offset @ up, offset @ forward


# --- projection between the world and the image ---------------------------------------------
def focal_length(video: VideoOptions) -> float:
    """Focal length in pixels of MuJoCo's free camera."""
    return cast(float, (video.height / 2) / np.tan(np.radians(FOVY) / 2))


def pixel_of(
    camera: CameraPose, video: VideoOptions, point: Sequence[float] | np.ndarray
) -> tuple[int, int]:
    """Pixel (row, column) where the world ``point`` appears in a frame (may lie outside it)."""
    right, up, depth = camera_coordinates(camera, point)
    focal = focal_length(video)
    column = video.width / 2 + focal * right / depth
    row = video.height / 2 - focal * up / depth
    return int(np.floor(row)), int(np.floor(column))


def x_at_column(
    camera: CameraPose, video: VideoOptions, column: float, y: float, z: float
) -> float:
    """The world x where the line (·, y, z) crosses image column ``column`` (the camera's right
    axis is horizontal, so this is the root of a linear equation)."""
    position, right, _, forward = camera_axes(camera)
    k = (column - video.width / 2) / focal_length(video)
    along = (y - position[1]) * right[1]
    ahead = (y - position[1]) * forward[1] + (z - position[2]) * forward[2]
    return float(position[0] + (k * ahead - along) / (right[0] - k * forward[0]))


def view_edges(camera: CameraPose, video: VideoOptions, y: float, z: float) -> tuple[float, float]:
    """The world x of the left and right frame edges on the line (·, y, z)."""
    return x_at_column(camera, video, 0.0, y, z), x_at_column(camera, video, video.width, y, z)


def image_point(
    camera: CameraPose, point: Sequence[float] | np.ndarray, aspect: float = 1.0
) -> tuple[float, float]:
    """Normalised image coordinates of a world point: (-1..1 left to right, -1..1 bottom to top)."""
    right, up, depth = camera_coordinates(camera, point)
    if depth <= 0:
        return math.inf, math.inf
    tan_half = math.tan(math.radians(FOVY) / 2)
    return float(right / (depth * tan_half * aspect)), float(up / (depth * tan_half))


def floor_point(
    camera: CameraPose, u: float, v: float, height: float, aspect: float = 1.0
) -> np.ndarray | None:
    """The point at ``height`` above the floor seen at image coordinates (u, v), or None when
    that pixel looks above the horizon."""
    position, right, up, forward = camera_axes(camera)
    tan_half = math.tan(math.radians(FOVY) / 2)
    ray = forward + u * tan_half * aspect * right + v * tan_half * up
    if ray[2] >= 0:
        return None
    return cast(np.ndarray, position + ray * (height - position[2]) / ray[2])


def height_above_view(camera: CameraPose, x: float, y: float) -> float:
    """The height at (x, y) above which the camera sees nothing (the top edge of the image)."""
    position, _, up, forward = camera_axes(camera)
    tan_half = math.tan(math.radians(FOVY) / 2)
    offset = np.array([x, y, 0.0]) - position
    # up-component = tan_half * forward-component, linear in the height z.
    denominator = up[2] - tan_half * forward[2]
    return float((tan_half * (offset @ forward) - offset @ up) / denominator)
