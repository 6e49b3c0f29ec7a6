"""Unchangeableness (paper §3): static objects keep their position, colour and shape while a
screen is lowered in front of them and raised again. Probes line 2-4 objects up in the
foreground, and each change (``position``, ``color``, ``shape``) is a quadruplet per seed: one
row seen with one value of the property throughout (A) or the other (B), and the two spliced
while the screen hides the row (AB, BA); the variants ``<change>`` and
``<change>_counterbalanced`` are its pairs (A, AB) and (B, BA). ``<change>_plus1``/``_plus2``
are plain pairs with one or two more objects than training ever shows (paper §5). Examples scatter the objects anywhere and drop a screen of any size at any depth
(half of them in the foreground, wide, as the probes' screen); the controls omit the screen
(``objects_only``) or the objects (``screen_only``). Examples, controls and probes share one
camera distribution, object sizes and screen motion (docs/architecture.md §4, "one world")."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes import recording
from voe_lightning.scenes.appearance import COLOR_NAMES, distinct_colors
from voe_lightning.scenes.builder import Geom, SceneBuilder, yaw_quat
from voe_lightning.scenes.camera import (
    CameraPose,
    CameraRange,
    VideoOptions,
    accept_any_video,
    floor_point,
    image_point,
)
from voe_lightning.scenes.recording import Video, draw_clip, pair_record, record_pair
from voe_lightning.scenes.sampling import RejectedSample, draw_until_valid, rng_for
from voe_lightning.scenes.screen import SCREEN_THICKNESS, Screen, draw_screen
from voe_lightning.scenes.simulation import SceneObject, Simulation, visible_ids

CONCEPT = "unchangeableness"
#: Its scenes render videos of any size and length (``scenes.check_video``).
check_video = accept_any_video
#: Objects in training clips and standard probes; generalization probes add one or two more.
MIN_OBJECTS, MAX_OBJECTS = 2, 4
OBJECT_SHAPES = ("sphere", "box", "cylinder", "capsule")
CHANGES = specs.UNCHANGEABLENESS_CHANGES
#: Widest row of probe objects (m): the camera must see all of them, plus1/plus2 included.
ROW_MAX_WIDTH = 1.8
#: The screen's lowest point when down: just above the floor, so nothing shows beneath it.
SCREEN_FLOOR_GAP = 0.002
#: Manipulated ids a probe record can carry (probe_record pads to this many).
MAX_MANIPULATED_IDS = 4
#: Objects a shape probe changes at most.
MOST_RESHAPED = 2
#: One camera distribution for examples, both controls and probes.
CAMERA = CameraRange(
    lookat_x=(-0.3, 0.3),
    lookat_y=(-0.3, 0.5),
    lookat_z=(0.1, 0.1),
    distance=(2.6, 3.6),
    azimuth=(80.0, 100.0),
    elevation=(-38.0, -24.0),
)
#: Footprint half-width of every object (probe rows shrink the top of it to fit their slots).
OBJECT_RADIUS = (0.11, 0.25)
#: Example screens (relative to the camera's look-at point, metres): anywhere, or in the
#: foreground across the middle, where probes put theirs; widths and heights of both kinds.
SCREEN_ANYWHERE = {"dx": (-1.2, 1.2), "dy": (-1.0, 1.4), "width": (0.5, 2.8)}
SCREEN_FOREGROUND = {"dx": (-0.2, 0.2), "dy": (-0.95, -0.15), "width": (1.4, 2.8)}
SCREEN_HEIGHT = (0.3, 1.2)
#: Share of example screens drawn in the foreground.
FOREGROUND_SHARE = 0.5


# --- objects -------------------------------------------------------------------------------------
@dataclass
class ObjectDraw:
    """One static object: its primitive shape, footprint half-width, height factor and colour."""

    shape: str
    radius: float
    height_factor: float
    yaw: float
    color: str

    def geoms(self) -> tuple[list[Geom], float]:
        """The object's geoms and the height of its body centre when it rests on the floor."""
        r = self.radius
        if self.shape == "sphere":
            return [Geom("sphere", [r])], r
        if self.shape == "box":
            half_height = 0.5 * r * (1.2 + 0.8 * self.height_factor)
            return [Geom("box", [0.78 * r, 0.78 * r, half_height])], half_height
        if self.shape == "cylinder":
            half_height = 0.5 * r * (1.5 + 1.0 * self.height_factor)
            return [Geom("cylinder", [r, half_height])], half_height
        if self.shape == "capsule":  # lying on its side: a pill, unlike the upright cylinder
            thickness = r * (0.5 + 0.15 * self.height_factor)
            lying = [math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0]
            return [Geom("capsule", [thickness, r - thickness], quat=lying)], thickness
        raise ValueError(f"unknown shape {self.shape!r}; valid shapes are: {OBJECT_SHAPES}")

    @property
    def height(self) -> float:
        return 2.0 * self.geoms()[1]

    @property
    def reach(self) -> float:
        """Largest horizontal distance of the object's surface from its centre (yawed box corners)."""
        return self.radius * (0.78 * math.sqrt(2.0) if self.shape == "box" else 1.0)


def draw_object(rng: np.random.Generator, radius: float, color: str) -> ObjectDraw:
    """A random primitive of footprint half-width ``radius`` and palette colour ``color``."""
    shape = OBJECT_SHAPES[rng.integers(len(OBJECT_SHAPES))]
    return ObjectDraw(shape, radius, float(rng.random()), float(rng.uniform(-0.6, 0.6)), color)


def add_object(
    builder: SceneBuilder,
    name: str,
    draw: ObjectDraw,
    x: float,
    y: float,
    replaces: str | None = None,
) -> SceneObject:
    """Add a static object resting on the floor at (x, y); a mocap body, so the hidden change
    can move it with sim.move. A twin swapped in for another object ``replaces`` it (its id)."""
    geoms, z = draw.geoms()
    quat = yaw_quat(draw.yaw)
    return builder.add(
        name, geoms, (x, y, z), draw.color, quat=quat, free=False, mocap=True, replaces=replaces
    )


def resting_position(draw: ObjectDraw, x: float, y: float) -> tuple[float, float, float]:
    return (x, y, draw.geoms()[1])


# --- probes --------------------------------------------------------------------------------------
def parse_variant(variant: str) -> tuple[str, int]:
    """(change, extra objects) of a probe variant: a quadruplet half (``color``,
    ``color_counterbalanced``) -> (``color``, 0); a generalization variant (``shape_plus2``)
    -> (``shape``, 2)."""
    change, _, extra = variant.removesuffix("_counterbalanced").partition("_plus")
    if variant not in specs.PROBE_VARIANTS[CONCEPT]:
        valid = ", ".join(specs.PROBE_VARIANTS[CONCEPT])
        raise ValueError(f"unknown unchangeableness variant {variant!r}; valid variants: {valid}")
    return change, int(extra or 0)


def _changed_count(rng: np.random.Generator, most: int) -> int:
    """How many objects change: one most often, more with decreasing probability."""
    weights = 0.5 ** np.arange(most)
    return int(rng.choice(np.arange(1, most + 1), p=weights / weights.sum()))


@dataclass
class ProbeLayout:
    """A probe's geometry: the camera, ``len(draws)`` objects in a row at ``xs`` (depth
    ``row_y``) and the screen in front of them."""

    camera: CameraPose
    draws: list[ObjectDraw]
    xs: np.ndarray
    row_y: float
    screen: Screen
    spare_colors: list[str]


def probe_layout(rng: np.random.Generator, count: int, video: VideoOptions) -> ProbeLayout:
    """Draw a probe's camera (from CAMERA), a row of ``count`` objects (sizes from the examples'
    range, shrunk to fit their slots) near where the camera looks, and a screen tall and wide
    enough to hide the row, just in front of it; RejectedSample if the row leaves the view."""
    camera = CAMERA.sample(rng)
    slot = min(float(rng.uniform(0.5, 0.7)), ROW_MAX_WIDTH / count)
    row_x = camera.lookat[0] + float(rng.uniform(-0.1, 0.1))
    row_y = camera.lookat[1] - float(rng.uniform(0.0, 0.3))
    xs = row_x + slot * (np.arange(count) - (count - 1) / 2)
    colors = [COLOR_NAMES[i] for i in rng.permutation(len(COLOR_NAMES))]
    largest_radius = min(OBJECT_RADIUS[1], 0.425 * slot)
    draws = [
        draw_object(rng, float(rng.uniform(OBJECT_RADIUS[0], largest_radius)), color)
        for color in colors[:count]
    ]
    aspect = video.width / video.height
    for x, draw in ((xs[0] - slot / 2, draws[0]), (xs[-1] + slot / 2, draws[-1])):
        if abs(image_point(camera, (x, row_y, draw.height), aspect)[0]) > 0.92:
            raise RejectedSample("the row does not fit in the view")
    largest = max(d.reach for d in draws)
    tallest = max(d.height for d in draws)
    screen_y = row_y - largest - float(rng.uniform(0.12, 0.3))
    margin = float(rng.uniform(0.25, 0.45))
    screen = draw_screen(
        rng,
        camera,
        video,
        row_x,
        screen_y,
        count * slot + 2 * margin,
        tallest + float(rng.uniform(0.35, 0.55)),
        SCREEN_FLOOR_GAP,
    )
    return ProbeLayout(camera, draws, xs, row_y, screen, colors[count:])


@dataclass
class ProbeScene:
    """A probe's built scene: the simulation of the row as drawn (shape twins taken out), its
    layout, the change frame (the screen fully down), the mask ids the change touches and the
    change itself (``change(sim)``: to the other value of the property, at any frame)."""

    sim: Simulation
    layout: ProbeLayout
    frame: int
    manipulated: list[int]
    change: Callable[[Simulation], None]


def _draw_change(
    change: str,
    rng: np.random.Generator,
    builder: SceneBuilder,
    layout: ProbeLayout,
    names: list[str],
) -> tuple[Callable[[Simulation], None], list[int], list[str]]:
    """(the change of ``change``'s property, the ids it touches, the bodies to take out once
    built) for the row ``names`` of ``layout``; a shape change adds its twins to ``builder``."""
    draws, xs, row_y, count = layout.draws, layout.xs, layout.row_y, len(names)
    if change == "position":
        # Move 2-4 objects to one another's places (a derangement: every chosen one moves).
        moved = int(rng.integers(2, min(count, MAX_MANIPULATED_IDS) + 1))
        chosen = rng.choice(count, moved, replace=False)
        targets = np.roll(chosen, int(rng.integers(1, moved)))

        def swap_places(sim: Simulation) -> None:
            for source, target in zip(chosen, targets):
                sim.move(names[source], resting_position(draws[source], float(xs[target]), row_y))

        return swap_places, [builder.objects[names[i]].mask_id for i in chosen], []
    if change == "color":
        recoloured = rng.choice(count, _changed_count(rng, min(count, 3)), replace=False)
        new_colors = layout.spare_colors[: len(recoloured)]

        def recolour(sim: Simulation) -> None:
            for index, color in zip(recoloured, new_colors):
                sim.set_color(names[index], color)

        return recolour, [builder.objects[names[i]].mask_id for i in recoloured], []
    # shape: each changed object swaps with a same-coloured twin of another shape, which takes
    # its mask id: to a tracker it is the same object, changed.
    reshaped = rng.choice(count, _changed_count(rng, MOST_RESHAPED), replace=False)
    twins = [f"twin{index}" for index in reshaped]
    for index, twin_name in zip(reshaped, twins):
        original = draws[index]
        others = [s for s in OBJECT_SHAPES if s != original.shape]
        twin = ObjectDraw(
            others[rng.integers(len(others))],
            original.radius,
            float(rng.random()),
            original.yaw,
            original.color,
        )
        add_object(builder, twin_name, twin, float(xs[index]), row_y, names[index])

    def swap_in_twins(sim: Simulation) -> None:
        for index, twin_name in zip(reshaped, twins):
            sim.remove(names[index])
            sim.restore(twin_name)

    return swap_in_twins, [builder.objects[names[i]].mask_id for i in reshaped], twins


def probe_scene(
    change: str, extra: int, video: VideoOptions, rng: np.random.Generator
) -> ProbeScene:
    """Draw and build a probe's scene: 2-4 objects in a row (``extra`` more for a
    generalization probe), the screen, a change frame while it is fully down and the change
    of ``change``'s property (``_draw_change``)."""
    count = int(rng.integers(MIN_OBJECTS, MAX_OBJECTS + 1)) if extra == 0 else MAX_OBJECTS + extra
    layout = probe_layout(rng, count, video)
    hidden = layout.screen.motion.hidden_frames()
    if not hidden:
        raise RejectedSample("the screen is never down for two frames in a row")
    frame = int(rng.choice(hidden))
    builder = SceneBuilder(rng, video, layout.camera)
    names = [f"object{i}" for i in range(count)]
    for name, draw, x in zip(names, layout.draws, layout.xs):
        add_object(builder, name, draw, float(x), layout.row_y)
    layout.screen.add_to(builder)
    apply, manipulated, taken_out = _draw_change(change, rng, builder, layout, names)
    sim = builder.build()
    for name in taken_out:
        sim.remove(name)
    return ProbeScene(sim, layout, frame, manipulated, apply)


def _check_pair(consistent: Video, inconsistent: Video, scene: ProbeScene) -> None:
    """Reject draws where the objects do not all show first, the screen does not hide the row at
    the change frame, or the change is not revealed at the end."""
    objects = set(range(1, len(scene.layout.draws) + 1))
    if visible_ids(consistent[1][0]) & objects != objects:
        raise RejectedSample("not every object is visible before the screen comes down")
    for _, masks, _ in (consistent, inconsistent):
        if visible_ids(masks[scene.frame]) & (objects | set(scene.manipulated)):
            raise RejectedSample("the screen does not hide the row at the manipulation")
    shown = visible_ids(consistent[1][-1]) | visible_ids(inconsistent[1][-1])
    changed_pixels = (consistent[0][-1] != inconsistent[0][-1]).any(axis=-1).sum()
    if not set(scene.manipulated) & shown or changed_pixels < 4:
        raise RejectedSample("the change is not revealed when the screen rises")


@functools.lru_cache(maxsize=4)
def quadruplet(change: str, seed: int, video: VideoOptions) -> recording.Quadruplet:
    """One scene draw's quadruplet of ``change`` ((A, AB), (B, BA)): A the row with the
    property's first value throughout, B with the other (``ProbeScene.change`` applied before
    the first frame), alike at the change frame, where the screen hides the whole row
    (``recording.quadruplet``); with the camera, that frame and the ids the change touches."""

    def make(rng: np.random.Generator) -> recording.Quadruplet:
        scene = probe_scene(change, 0, video, rng)
        second = scene.sim.fork()
        scene.change(second)
        videos = [
            sim.record(video.num_frames, scene.layout.screen.script) for sim in (scene.sim, second)
        ]
        pairs = recording.quadruplet(videos[0], videos[1], scene.frame)
        for pair in pairs:
            _check_pair(*pair, scene)
        return pairs, scene.layout.camera.as_array(), scene.frame, tuple(scene.manipulated)

    return draw_until_valid(make, rng_for(seed, CONCEPT, change, "quadruplet"))


def _generalization_probe(
    change: str, extra: int, variant: str, seed: int, video: VideoOptions, rng: np.random.Generator
) -> TensorDict:
    """A plain pair of ``extra`` more objects than training: the row, changed behind the
    screen at the change frame in the inconsistent video (``recording.record_pair``)."""
    scene = probe_scene(change, extra, video, rng)
    consistent, inconsistent = record_pair(
        scene.sim, scene.frame, scene.change, script=scene.layout.screen.script
    )
    _check_pair(consistent, inconsistent, scene)
    return pair_record(
        CONCEPT,
        variant,
        seed,
        (consistent, inconsistent),
        scene.layout.camera.as_array(),
        scene.frame,
        scene.manipulated,
    )


def probe(variant: str, seed: int, video: VideoOptions) -> TensorDict:
    """A consistent/inconsistent probe pair: objects in a row, screen down and up. A change's
    two variants (``color``, ``color_counterbalanced``) are the halves of the seed's
    quadruplet (``quadruplet``): the row keeps its property, or it changes behind the screen
    to the other half's value. A generalization variant (``color_plus1``) is a plain pair."""
    change, extra = parse_variant(variant)
    if extra == 0:
        return recording.quadruplet_record(CONCEPT, variant, seed, quadruplet(change, seed, video))
    # Separate salt words: rng_for reads only the first 8 bytes of each word.
    rng = rng_for(seed, CONCEPT, change, f"plus{extra}")
    return draw_until_valid(
        lambda r: _generalization_probe(change, extra, variant, seed, video, r), rng
    )


# --- training clips ------------------------------------------------------------------------------
def draw_example_screen(
    rng: np.random.Generator, camera: CameraPose, video: VideoOptions
) -> Screen:
    """A screen of any size at any depth from the foreground to the background, or (half of
    them) wide across the foreground as in probes; it may stop above the floor, so objects are
    hidden partly, wholly or not at all, at different times."""
    ranges = SCREEN_FOREGROUND if rng.random() < FOREGROUND_SHARE else SCREEN_ANYWHERE
    x = float(camera.lookat[0] + rng.uniform(*ranges["dx"]))
    y = float(camera.lookat[1] + rng.uniform(*ranges["dy"]))
    width = float(rng.uniform(*ranges["width"]))
    height = float(rng.uniform(*SCREEN_HEIGHT))
    bottom = SCREEN_FLOOR_GAP if rng.random() < 0.7 else float(rng.uniform(0.05, 0.4))
    return draw_screen(rng, camera, video, x, y, width, height, bottom)


def _clear_of_screen(screen: Screen | None, draw: ObjectDraw, x: float, y: float) -> bool:
    if screen is None:
        return True
    return (
        abs(x - screen.x) > screen.width / 2 + draw.reach + 0.05
        or abs(y - screen.y) > SCREEN_THICKNESS / 2 + draw.reach + 0.05
    )


def scatter_objects(
    rng: np.random.Generator, camera: CameraPose, screen: Screen | None, aspect: float
) -> list[tuple[ObjectDraw, float, float]]:
    """2-4 static objects (draw, x, y) anywhere in view (uniformly over the image, up to 2.5 m
    past the point the camera looks at), apart from one another and the screen."""
    count = int(rng.integers(MIN_OBJECTS, MAX_OBJECTS + 1))
    colors = distinct_colors(rng, count)
    placed: list[tuple[float, float, float]] = []
    objects = []
    for color in colors:
        draw = draw_object(rng, float(rng.uniform(*OBJECT_RADIUS)), str(color))
        for _ in range(100):
            u, v = rng.uniform(-0.85, 0.85, size=2)
            point = floor_point(camera, u, v, draw.height / 2, aspect)
            if point is None:
                continue
            x, y = float(point[0]), float(point[1])
            if (
                math.dist((x, y), camera.lookat[:2]) < 2.5
                and _clear_of_screen(screen, draw, x, y)
                and all(
                    math.hypot(x - px, y - py) > draw.reach + pr + 0.08 for px, py, pr in placed
                )
            ):
                break
        else:
            raise RejectedSample("no free place in view for an object")
        placed.append((x, y, draw.reach))
        objects.append((draw, x, y))
    return objects


def clip(kind: str, seed: int, video: VideoOptions) -> TensorDict:
    """A training clip: ``example`` (scattered objects and a screen going down and up),
    ``objects_only`` (no screen) or ``screen_only`` (no objects)."""

    def draw_scene(rng: np.random.Generator) -> tuple[CameraPose, Video]:
        camera = CAMERA.sample(rng)
        aspect = video.width / video.height
        builder = SceneBuilder(rng, video, camera)
        screen = draw_example_screen(rng, camera, video) if kind != "objects_only" else None
        if kind != "screen_only":
            for index, (draw, x, y) in enumerate(scatter_objects(rng, camera, screen, aspect)):
                add_object(builder, f"object{index}", draw, x, y)
        if screen is not None:
            screen.add_to(builder)
        sim = builder.build()
        return camera, sim.record(video.num_frames, screen.script if screen else None)

    return draw_clip(CONCEPT, kind, seed, draw_scene)
