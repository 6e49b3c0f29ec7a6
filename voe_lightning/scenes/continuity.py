"""Continuity (paper §3, after Aguilar & Baillargeon 1999): a ball rolls behind two pillars.
``standard`` and ``counterbalanced`` are one quadruplet per seed, on the ``gap_block`` layout (a
block fills the gap, so pillars and block are one long screen): A is the roll from its launch,
B the same roll k frames later, both wholly behind the screen at the manipulation frame. The
standard inconsistent video (A, then B) shows the ball come out of the screen k frames too
soon, as if it had jumped across part of it; the counterbalanced one (B, then A) k frames too
late, as if it had stopped unseen. Both videos of a pair lose and find the ball at the same
places, unseen for as long in sum, so no rule without dynamics tells them apart (issue 70). The
``paper`` variant keeps the paper's own probe (an open gap the ball crosses unseen), which no
splice of two physical videos gives (docs/stimuli.md); it is reported beside the quadruplets.
Examples roll free or slowing balls on unconstrained paths past the same pillars."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.scenes import recording
from voe_lightning.scenes.appearance import distinct_colors
from voe_lightning.scenes.ball_sight import (
    at_frame_edge,
    ball_pixels,
    column,
    full_ball_pixels,
    what_hides_ball,
)
from voe_lightning.scenes.builder import SceneBuilder
from voe_lightning.scenes.camera import (
    CameraPose,
    CameraRange,
    VideoOptions,
    view_edges,
    x_at_column,
)
from voe_lightning.scenes.recording import (
    Video,
    draw_clip,
    head,
    join,
    pair_record,
    quadruplet_record,
    record_tracking,
    splice,
    tail,
)
from voe_lightning.scenes.sampling import RejectedSample, draw_until_valid, rng_for
from voe_lightning.scenes.simulation import Simulation

CONCEPT = "continuity"
#: The one camera distribution of the concept: examples, the gap_block control and every probe
#: draw from it. Close enough that the ball is 8-12 px across at 64x64.
CAMERA = CameraRange(
    lookat_x=(-0.1, 0.1),
    lookat_y=(0.2, 0.45),
    lookat_z=(0.25, 0.35),
    distance=(3.1, 3.5),
    azimuth=(87.0, 93.0),
    elevation=(-24.0, -16.0),
)
PILLAR_DEPTH = 0.12
#: A ball counts as seen when at least this share of its largest visible area shows.
VISIBLE_SHARE = 0.5

#: A (low, high) range of a uniform draw.
Range = tuple[float, float]
#: Parameter ranges (uniform). Probes draw inside the examples' ranges (docs/architecture.md §4).
PILLAR_WIDTH = (0.42, 0.55)
GAP = (0.45, 0.9)
THREE_PILLAR_GAP = (0.8, 0.9)  # the outer pair as in training, from the wide end of GAP
MIDDLE_PILLAR_WIDTH = (0.2, 0.26)  # the generalization probe's extra pillar (never in training)
PROBE_PILLAR_HEIGHT = (0.75, 1.0)
EXAMPLE_PILLAR_HEIGHT = (0.5, 1.2)
PROBE_BALL_RADIUS = (0.17, 0.21)
EXAMPLE_BALL_RADIUS = (0.13, 0.24)
PROBE_BALL_DEPTH = (0.35, 0.6)  # behind the pillars
EXAMPLE_BALL_DEPTH = (-0.9, 1.0)  # in front of or behind them
PROBE_SPEED = (0.55, 1.2)
#: Where a quadruplet's ball starts, as a share of the room before the screen (the probes': all
#: of it): near the frame edge, so it is seen long enough before the screen for the shift.
QUADRUPLET_START_SHARE = 0.15
#: A quadruplet's screen (gap, pillar width) from the narrow end of the training ranges, and where
#: A's ball ends (a share of the room past it): room for B's ball, k frames on, to end in view.
QUADRUPLET_SCREEN = ((0.45, 0.6), (0.42, 0.46))
QUADRUPLET_END_SHARE = 0.1
#: The least time by which a quadruplet's inconsistent ball comes out too soon or too late.
QUADRUPLET_MIN_SHIFT = 0.4
EXAMPLE_SPEED = (0.4, 1.5)
#: MuJoCo rolling friction (a length, contact dimension 6): 0 rolls freely (every probe).
EXAMPLE_ROLLING_FRICTION = (0.005, 0.045)
EXAMPLE_SLOWING_SHARE = 0.5  # share of examples whose ball slows down (and often stops)


@dataclass
class Layout:
    """One continuity scene: pillars (centre x, width) in the plane y = 0, an optional block
    filling the gap between the outer two, and a ball launched rolling from ``ball_start`` with
    ``rolling_friction`` (0: it rolls on at constant speed; more: it slows and stops)."""

    pillars: list[tuple[float, float]]
    pillar_height: float
    ball_radius: float
    ball_start: tuple[float, float, float]
    ball_velocity: tuple[float, float]
    rolling_friction: float = 0.0
    gap_block_height: float | None = None

    def outer_pillars(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """(centre x, width) of the leftmost and rightmost pillars."""
        ordered = sorted(self.pillars)
        return ordered[0], ordered[-1]

    def gap_edges(self) -> tuple[float, float]:
        """x of the inner faces of the outermost pillars (the gap a block fills)."""
        (left_x, left_w), (right_x, right_w) = self.outer_pillars()
        return left_x + left_w / 2, right_x - right_w / 2

    def parameters(self) -> dict[str, float]:
        """The scalar parameters probes must share with examples (pillar width of the outer
        pair; the gap between them; the ball's depth behind the pillar plane and speed)."""
        (_, left_w), _ = self.outer_pillars()
        low, high = self.gap_edges()
        return {
            "pillar_width": left_w,
            "gap": high - low,
            "pillar_height": self.pillar_height,
            "ball_radius": self.ball_radius,
            "ball_depth": self.ball_start[1],
            "speed": float(np.hypot(*self.ball_velocity)),
            "rolling_friction": self.rolling_friction,
        }


def build(
    rng: np.random.Generator, video: VideoOptions, camera: CameraPose, layout: Layout
) -> Simulation:
    """Compile the scene and launch the ball rolling (spin matched to its speed, no slip)."""
    builder = SceneBuilder(rng, video, camera)
    pillar_color, block_color, ball_color = distinct_colors(rng, 3)
    height = layout.pillar_height
    for index, (x, width) in enumerate(layout.pillars):
        builder.add_primitive(
            f"pillar{index}",
            "box",
            (width / 2, PILLAR_DEPTH / 2, height / 2),
            (x, 0.0, height / 2),
            pillar_color,
            free=False,
        )
    if layout.gap_block_height is not None:
        inner_left, inner_right = layout.gap_edges()
        block_height = layout.gap_block_height
        builder.add_primitive(
            "block",
            "box",
            ((inner_right - inner_left) / 2, PILLAR_DEPTH / 2, block_height / 2),
            ((inner_left + inner_right) / 2, 0.0, block_height / 2),
            block_color,
            free=False,
        )
    radius = layout.ball_radius
    builder.add_primitive("ball", "sphere", (radius,), layout.ball_start, ball_color, density=300.0)
    if layout.rolling_friction > 0:
        ball = builder.spec.geom("ball_0")
        ball.condim = 6  # sliding, torsional and rolling friction
        ball.friction = [0.8, 0.005, layout.rolling_friction]
    sim = builder.build()
    launch(sim, layout.ball_start, layout.ball_velocity)
    return sim


def launch(
    sim: Simulation, start: tuple[float, float, float], velocity: tuple[float, float]
) -> None:
    """Place the ball at ``start`` rolling with horizontal ``velocity`` (spin without slip)."""
    radius = float(sim.model.geom("ball_0").size[0])
    vx, vy = velocity
    sim.move("ball", start)
    sim.set_velocity("ball", (vx, vy, 0.0), (-vy / radius, vx / radius, 0.0))


def _pillars(
    rng: np.random.Generator, num_pillars: int, screen: tuple[Range, Range] = (GAP, PILLAR_WIDTH)
) -> tuple[list[float], list[float]]:
    """Pillar centres (around 0) and widths: a pair (its gap and width drawn from ``screen``),
    or the three-pillar probe's pair from the wide end of the training gaps with a narrow
    pillar in the middle."""
    width = float(rng.uniform(*screen[1]))
    if num_pillars == 2:
        gap = float(rng.uniform(*screen[0]))
        return [-(gap + width) / 2, (gap + width) / 2], [width, width]
    gap = float(rng.uniform(*THREE_PILLAR_GAP))
    middle = float(rng.uniform(*MIDDLE_PILLAR_WIDTH))
    return [-(gap + width) / 2, 0.0, (gap + width) / 2], [width, middle, width]


def probe_layout(
    rng: np.random.Generator,
    variant: str,
    camera: CameraPose,
    video: VideoOptions,
    start_share: float = 1.0,
    end_share: float = 1.0,
    screen: tuple[Range, Range] = (GAP, PILLAR_WIDTH),
) -> Layout:
    """Pillars a little upstream of the view's centre (three for ``three_pillars``, else two)
    and a ball rolling freely behind them at constant speed from the frame edge or nearer (up to
    ``start_share`` of the way to the first pillar), ending in view past the last pillar (up to
    ``end_share`` of the way from it to the far edge; RejectedSample if that needs a speed
    outside PROBE_SPEED); two pillars' gap and width drawn from ``screen``."""
    centres, widths = _pillars(rng, 3 if variant == "three_pillars" else 2, screen)
    radius = float(rng.uniform(*PROBE_BALL_RADIUS))
    depth = float(rng.uniform(*PROBE_BALL_DEPTH))
    direction = float(rng.choice([-1.0, 1.0]))
    middle = x_at_column(camera, video, video.width / 2, 0.0, radius)
    # Upstream of the view's centre, leaving room to roll on (or reappear) past the last pillar.
    shift = middle - direction * float(rng.uniform(0.0, 0.25))
    pillars = [(c + shift, w) for c, w in zip(centres, widths)]
    height = float(rng.uniform(*PROBE_PILLAR_HEIGHT))
    ordered = sorted(pillars, key=lambda pillar: direction * pillar[0])
    (first_x, first_w), (last_x, last_w) = ordered[0], ordered[-1]
    upstream, downstream = view_edges(camera, video, depth, radius)[:: int(direction)]
    # Start anywhere from half in view at the edge to just before the first pillar; end wholly
    # in view past the last one; the speed follows.
    before = first_x - direction * (first_w / 2 + radius + 0.05)
    past, inside = (
        last_x + direction * (last_w / 2 + radius + 0.1),
        downstream - 1.2 * direction * radius,
    )
    if direction * (before - upstream) < 0 or direction * (inside - past) < 0:
        raise RejectedSample("the pillars leave no room in view before or after them")
    start = upstream + start_share * float(rng.random()) * (before - upstream)
    end = past + end_share * float(rng.random()) * (inside - past)
    speed = direction * (end - start) / ((video.num_frames - 1) * video.duration / video.num_frames)
    if not PROBE_SPEED[0] <= speed <= PROBE_SPEED[1]:
        raise RejectedSample(f"the ball would roll at {speed:.2f} m/s, outside {PROBE_SPEED}")
    return Layout(pillars, height, radius, (start, depth, radius), (direction * speed, 0.0))


def example_layout(rng: np.random.Generator, duration: float) -> Layout:
    """Two pillars and a ball whose path is unconstrained: in front of or behind the pillars,
    any speed, either direction, slanted, sometimes dropped from a little height, and in half
    the clips slowing down under rolling friction (often to a standstill)."""
    centres, widths = _pillars(rng, 2)
    shift = float(rng.uniform(-0.5, 0.5))
    radius = float(rng.uniform(*EXAMPLE_BALL_RADIUS))
    angle = float(rng.uniform(-0.35, 0.35))
    speed = float(rng.uniform(*EXAMPLE_SPEED))
    direction = float(rng.choice([-1.0, 1.0]))
    drop = float(rng.uniform(0.0, 0.5)) if rng.random() < 0.3 else 0.0
    start = (
        float(-direction * rng.uniform(0.3, 1.5)),
        float(rng.uniform(*EXAMPLE_BALL_DEPTH)),
        radius + drop,
    )
    slowing = rng.random() < EXAMPLE_SLOWING_SHARE
    friction = float(rng.uniform(*EXAMPLE_ROLLING_FRICTION)) if slowing else 0.0
    return Layout(
        pillars=[(c + shift, w) for c, w in zip(centres, widths)],
        pillar_height=float(rng.uniform(*EXAMPLE_PILLAR_HEIGHT)),
        ball_radius=radius,
        ball_start=start,
        ball_velocity=(direction * speed * np.cos(angle), speed * np.sin(angle)),
        rolling_friction=friction,
    )


def path_pillars(layout: Layout) -> list[int]:
    """Pillar indices in the order the ball passes them."""
    order = sorted(range(len(layout.pillars)), key=lambda i: layout.pillars[i][0])
    return order[::-1] if layout.ball_velocity[0] < 0 else order


def vanish_and_reappear(
    sim: Simulation, layout: Layout, masks: np.ndarray, positions: np.ndarray
) -> tuple[int, int]:
    """The first frame the ball is wholly hidden by the first pillar on its path and the first
    after that it is wholly hidden by the last one; rejects scenes where the ball is not seen
    well before, in every gap between, and after the pillars, or not wholly in the last frame."""
    ball = sim.mask_id("ball")
    pixels = ball_pixels(masks, ball)
    seen = what_hides_ball(sim, masks, positions)
    order = path_pillars(layout)
    first, last = (sim.mask_id(f"pillar{i}") for i in (order[0], order[-1]))
    vanish = first_hidden(seen, pixels, first, 1)
    reappear = first_hidden(seen, pixels, last, vanish + 1)
    full = full_ball_pixels(sim, layout.ball_radius, layout.ball_start[1])
    well_seen = pixels >= VISIBLE_SHARE * full
    if not well_seen[:vanish].any():
        raise RejectedSample("the ball is not seen before the first pillar")
    if not well_seen[-1]:
        raise RejectedSample("the ball is not seen whole in the last frame")
    ball_columns = np.array([column(sim, position) for position in positions])
    pillar_columns = [column(sim, (layout.pillars[i][0], 0.0, 0.0)) for i in order]
    for one, other in zip(pillar_columns, pillar_columns[1:]):
        low, high = min(one, other), max(one, other)
        in_gap = (low < ball_columns) & (ball_columns < high) & well_seen
        if not in_gap[vanish:reappear].any():
            raise RejectedSample("the ball is not seen in every gap between the pillars")
    return vanish, reappear


def first_hidden(seen: np.ndarray, pixels: np.ndarray, occluder: int, after: int) -> int:
    """The first frame from ``after`` on where ``occluder`` wholly hides the ball."""
    hidden = np.flatnonzero((seen == occluder) & (pixels == 0))
    hidden = hidden[hidden >= after]
    if not len(hidden):
        raise RejectedSample(f"the ball is never wholly hidden by occluder {occluder}")
    return int(hidden[0])


def _standard(
    rng: np.random.Generator, variant: str, video: VideoOptions, camera: CameraPose
) -> tuple[Simulation, Video, Video, int]:
    """The paper's pair: the consistent video rendered whole; the inconsistent one forks at the
    frame the ball is hidden by the first pillar, parks the ball, and restores the consistent
    state (ball on course) at the frame it is hidden by the last pillar."""
    layout = probe_layout(rng, variant, camera, video)
    sim = build(rng, video, camera, layout)
    consistent, states, positions = record_tracking(sim, "ball")
    vanish, reappear = vanish_and_reappear(sim, layout, consistent[1], positions)
    twin = sim.fork()
    twin.set_state(states[vanish])
    twin.remove("ball")

    def reappear_on_course(twin: Simulation, frame: int) -> None:
        if frame == reappear:
            twin.restore("ball")
            twin.set_state(states[reappear])

    rest = twin.record(video.num_frames - vanish, reappear_on_course, first_frame=vanish)
    return sim, consistent, splice(consistent, rest, vanish), vanish


def gap_block_layout(
    rng: np.random.Generator,
    camera: CameraPose,
    video: VideoOptions,
    quadruplet: bool = False,
) -> Layout:
    """The standard probe's pillars and ball (``probe_layout``; a ``quadruplet``'s narrower, its
    ball from near the frame's edge to near the screen) with a block 0.75 to 1 times their
    height filling the gap: one long screen the ball is hidden behind throughout."""
    shares = (QUADRUPLET_START_SHARE, QUADRUPLET_END_SHARE) if quadruplet else (1.0, 1.0)
    screen = QUADRUPLET_SCREEN if quadruplet else (GAP, PILLAR_WIDTH)
    layout = probe_layout(rng, "standard", camera, video, *shares, screen)
    layout.gap_block_height = layout.pillar_height * float(rng.uniform(0.75, 1.0))
    return layout


def check_hidden_over_block(
    sim: Simulation, layout: Layout, masks: np.ndarray, positions: np.ndarray
) -> None:
    """RejectedSample unless the block hides the ball somewhere and never shows it above."""
    pixels = ball_pixels(masks, sim.mask_id("ball"))
    if not (what_hides_ball(sim, masks, positions) == sim.mask_id("block")).any():
        raise RejectedSample("the block never hides the ball")
    low, high = sorted(column(sim, (x, 0.0, 0.0)) for x in layout.gap_edges())
    for t, position in enumerate(positions):
        if low < column(sim, position) < high and pixels[t]:
            raise RejectedSample("the ball shows above the gap block")


def behind_the_screen(sim: Simulation, layout: Layout, masks: np.ndarray) -> tuple[int, int, int]:
    """Of a roll past the gap_block screen: the last frame the ball is well seen before it, the
    first frame it is wholly hidden and the first it shows again (RejectedSample if it is not
    well seen before and after the screen)."""
    pixels = ball_pixels(masks, sim.mask_id("ball"))
    full = full_ball_pixels(sim, layout.ball_radius, layout.ball_start[1])
    well_seen = pixels >= VISIBLE_SHARE * full
    if not well_seen.any():
        raise RejectedSample("the ball is never well seen")
    hidden = np.flatnonzero(pixels == 0)
    hidden = hidden[hidden > np.argmax(well_seen)]
    if not len(hidden):
        raise RejectedSample("the ball never goes wholly behind the screen")
    vanish = int(hidden[0])
    shown = np.flatnonzero(pixels[vanish:] > 0)
    if not len(shown) or not well_seen[vanish + int(shown[0]) :].any():
        raise RejectedSample("the ball is not well seen after the screen")
    return int(np.flatnonzero(well_seen[:vanish])[-1]), vanish, vanish + int(shown[0])


def quadruplet_min_shift(video: VideoOptions) -> int:
    """The fewest frames by which a quadruplet's inconsistent ball comes out too soon or too
    late: the whole frames in QUADRUPLET_MIN_SHIFT at ``video``'s frame rate, one at least (2 at
    the paper's 5 fps)."""
    return max(1, math.floor(QUADRUPLET_MIN_SHIFT * video.fps + 1e-9))


def _quadruplet(
    rng: np.random.Generator, video: VideoOptions, camera: CameraPose
) -> tuple[Simulation, tuple[tuple[Video, Video], tuple[Video, Video]], int]:
    """One roll behind the gap_block screen seen from two moments: A from the launch, B the
    same roll k frames later, k as large as leaves B's ball well seen before m (A's first
    frame with the ball wholly hidden), still hidden at m and off the frame's edge to its last
    frame, and at least QUADRUPLET_MIN_SHIFT.
    Both show nothing of the ball at m, so they render alike there; AB's ball comes out k
    frames too soon, BA's k frames too late, at the same place as in A and B. From m on neither
    shows the ball at the frame's edge: the two futures differ in when it comes out, not in
    whether it leaves the view."""
    layout = gap_block_layout(rng, camera, video, quadruplet=True)
    sim = build(rng, video, camera, layout)
    first, _, positions = record_tracking(sim, "ball")
    check_hidden_over_block(sim, layout, first[1], positions)
    last_seen, vanish, back = behind_the_screen(sim, layout, first[1])
    ball = sim.mask_id("ball")
    if at_frame_edge(first[1], ball)[vanish:].any():
        raise RejectedSample("the ball reaches the frame's edge after the change")
    later = min(last_seen, back - vanish - 1)
    beyond = sim.record(later)  # A's roll on after its last frame, as far as B may go
    edge = np.flatnonzero(at_frame_edge(beyond[1], ball))
    later = min(later, int(edge[0])) if len(edge) else later  # B's ball off the edge too
    if later < quadruplet_min_shift(video):
        raise RejectedSample(f"the ball can come out only {later} frames too soon or too late")
    second = join(tail(first, later), head(beyond, later))
    return sim, recording.quadruplet(first, second, vanish), vanish


#: The fewest frames a quadruplet is drawn in: in fewer, the ball is seen in at most one frame
#: before the screen on most draws, so its exit cannot come a frame too soon (``check_video``).
QUADRUPLET_MIN_FRAMES = 8


def check_video(video: VideoOptions) -> None:
    """Refuse videos too short for the probes (QUADRUPLET_MIN_FRAMES); ``generate`` calls it
    before rendering anything. Training clips render at any length."""
    if video.num_frames < QUADRUPLET_MIN_FRAMES:
        raise ValueError(
            f"{CONCEPT} probes need num_frames >= {QUADRUPLET_MIN_FRAMES} (the ball seen in two "
            f"frames before the screen, so that it can come out a frame too soon), got "
            f"{video.num_frames}"
        )


@functools.lru_cache(maxsize=4)
def quadruplet(seed: int, video: VideoOptions) -> recording.Quadruplet:
    """One scene draw's quadruplet ((A, AB), (B, BA)) (``_quadruplet``), with the camera, the
    manipulation frame and the ball's mask id. Cached, as both variants of a seed read it
    (callers copy what they keep)."""
    check_video(video)

    def make(rng: np.random.Generator) -> recording.Quadruplet:
        camera = CAMERA.sample(rng)
        sim, pairs, vanish = _quadruplet(rng, video, camera)
        return pairs, camera.as_array(), vanish, sim.mask_id("ball")

    return draw_until_valid(make, rng_for(seed, CONCEPT, "quadruplet"))


def probe(variant: str, seed: int, video: VideoOptions) -> TensorDict:
    """A consistent/inconsistent pair: ``standard`` and ``counterbalanced``, the two halves of
    the seed's quadruplet (``quadruplet``); ``paper`` (the paper's probe, the ball reappearing
    when it would have, which no splice gives) or ``three_pillars`` (the generalization probe).
    The camera is drawn from CAMERA like every training clip's."""
    specs.check_variant(CONCEPT, variant)
    if variant in specs.VERDICT_VARIANTS[CONCEPT]:
        return quadruplet_record(CONCEPT, variant, seed, quadruplet(seed, video))

    def make(rng: np.random.Generator) -> TensorDict:
        camera = CAMERA.sample(rng)
        sim, consistent, inconsistent, vanish = _standard(rng, variant, video, camera)
        pair = (consistent, inconsistent)
        return pair_record(
            CONCEPT, variant, seed, pair, camera.as_array(), vanish, [sim.mask_id("ball")]
        )

    return draw_until_valid(make, rng_for(seed, CONCEPT, variant))


def clip(kind: str, seed: int, video: VideoOptions) -> TensorDict:
    """A training clip: an ``example`` with an unconstrained ball path, or the ``gap_block``
    control where a block fills the gap so the ball shows only before and after the pillars
    (the standard probe's path and ball). Both draw the camera from CAMERA."""

    def draw_scene(rng: np.random.Generator) -> tuple[CameraPose, Video]:
        camera = CAMERA.sample(rng)
        if kind == "example":
            layout = example_layout(rng, video.duration)
        else:
            layout = gap_block_layout(rng, camera, video)
        sim = build(rng, video, camera, layout)
        (frames, masks, objects), _, positions = record_tracking(sim, "ball")
        pixels = ball_pixels(masks, sim.mask_id("ball"))
        if (pixels > 0).sum() < video.num_frames / 3:
            raise RejectedSample("the ball is seen in less than a third of the frames")
        if kind == "gap_block":
            check_hidden_over_block(sim, layout, masks, positions)
        return camera, (frames, masks, objects)

    return draw_clip(CONCEPT, kind, seed, draw_scene)
