"""What a renderer of object boxes would show: camera coordinates, image-plane boxes and which
points of an object no other object hides. The positive control (``object_state``) starts its
visibility from this geometry and learns the rest; all of it is differentiable, so the dynamics
of a hidden object learn from whether it was expected to be seen. ``draw_ellipses`` draws object
states as they would be seen (the control's expected frames in the report)."""

from __future__ import annotations

import math
from typing import cast

import torch
import torch.nn.functional as F

from voe_lightning import specs
from voe_lightning.scenes.camera import FOVY

#: Where an object is in the view (``view``): camera coordinates (right, up, depth), and the
#: centre and half-extents (right, up) of its bounding box in the image plane.
VIEW = 3 + 2 + 2
COMPOUND = specs.OBJECT_SHAPES.index("compound")
#: The points of an object's box whose sight lines are tested: its centre and its eight corners
#: drawn in to this share of the half-extents (a corner exactly on a touching face is moot).
CORNER_INSET = 0.9
#: Half-thickness (m) of the walls and bottom of an open container (a ``compound`` object is an
#: open-topped box of its bounding box: what lies inside it is seen over its rim, not through
#: its walls).
WALL = 0.02
#: How far (m) below an object's lowest point the top of what it rests on may be: one resting
#: on another touches it (``pivoted_down``).
REST_TOLERANCE = 0.05
#: Softness (m) of the sight-line tests: how far a sight line must pass through a box, or a
#: point lie above the floor, to count as clearly hidden or clearly not.
SOFTNESS = 0.01
#: How far a corner of each shape's box (``specs.OBJECT_SHAPES``) must be drawn in to lie inside
#: the shape: a sphere's by sqrt(3), a cylinder's or capsule's by sqrt(2), a box's not at all.
ROUNDNESS = tuple(
    {
        "sphere": math.sqrt(3),
        "ellipsoid": math.sqrt(3),
        "cylinder": math.sqrt(2),
        "capsule": math.sqrt(2),
    }.get(name, 1.0)
    for name in specs.OBJECT_SHAPES
)


def camera_axes(camera: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Eye position, right, up and forward unit vectors [B, 3] of MuJoCo's free camera at
    poses [B, 6] (the torch twin of ``scenes.camera.camera_axes``)."""
    azimuth, elevation = torch.deg2rad(camera[:, 4]), torch.deg2rad(camera[:, 5])
    forward = torch.stack(
        [elevation.cos() * azimuth.cos(), elevation.cos() * azimuth.sin(), elevation.sin()], dim=-1
    )
    up = torch.stack(
        [-elevation.sin() * azimuth.cos(), -elevation.sin() * azimuth.sin(), elevation.cos()],
        dim=-1,
    )
    eye = camera[:, :3] - camera[:, 3:4] * forward
    return eye, torch.linalg.cross(forward, up), up, forward


def _product_map() -> torch.Tensor:
    """The rotation matrix of a quaternion (w, x, y, z), less the identity, as a linear map of
    its sixteen pairwise products q_a q_b [16, 9] (row 4a + b; column: the entry, row-major)."""
    w, x, y, z = range(4)
    entries = [
        ((y, y, -2), (z, z, -2)),
        ((x, y, 2), (w, z, -2)),
        ((x, z, 2), (w, y, 2)),
        ((x, y, 2), (w, z, 2)),
        ((x, x, -2), (z, z, -2)),
        ((y, z, 2), (w, x, -2)),
        ((x, z, 2), (w, y, -2)),
        ((y, z, 2), (w, x, 2)),
        ((x, x, -2), (y, y, -2)),
    ]
    mapping = torch.zeros(16, 9)
    for entry, terms in enumerate(entries):
        for a, b, coefficient in terms:
            mapping[4 * a + b, entry] = coefficient
    return mapping


#: One matrix product in place of some thirty element-wise operations: the positive control
#: turns every object's quaternion into a matrix some twenty times a frame, forward and back.
PRODUCT_MAP = _product_map()
IDENTITY = torch.eye(3).flatten()


def _rotation(quaternion: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [..., 3, 3] of quaternions [..., 4] (w, x, y, z; zeros give the
    identity)."""
    products = (quaternion[..., :, None] * quaternion[..., None, :]).flatten(-2)
    return (products @ PRODUCT_MAP.to(quaternion) + IDENTITY.to(quaternion)).unflatten(-1, (3, 3))  # type: ignore[no-untyped-call, no-any-return]  # Tensor.unflatten: unannotated in torch


def quaternion_matrix(quaternion: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [..., 3, 3] of quaternions [..., 4] (w, x, y, z; zeros give zeros)."""
    return cast(
        torch.Tensor, _rotation(quaternion) * (quaternion.norm(dim=-1) > 0)[..., None, None]
    )


def image_plane(coordinates: torch.Tensor) -> torch.Tensor:
    """Camera coordinates [..., 3] -> image-plane position [..., 2] in units of the half
    field of view (inside the image: both within [-1, 1])."""
    depth = coordinates[..., 2:3].clamp(min=0.05)
    return coordinates[..., :2] / depth / math.tan(math.radians(FOVY) / 2)


def view(state: torch.Tensor, camera: torch.Tensor) -> torch.Tensor:
    """Where objects of ``state`` [B, S, 13] (position, orientation, half-size, colour) are
    seen from poses [B, 6]: camera coordinates, and the centre and half-extents of each one's
    bounding box in the image plane (the box's extent along the camera's right and up axes over
    its depth) [B, S, VIEW]."""
    eye, right, up, forward = camera_axes(camera)
    axes = torch.stack([right, up, forward], dim=-1)  # [B, 3, 3], columns: the camera's axes
    coordinates = (state[..., :3] - eye[:, None]) @ axes
    body_axes = quaternion_matrix(state[..., 3:7])  # columns: the body's axes in the world
    # each body axis along the camera's right and up [B, S, 2, 3], times the half-sizes
    extents = ((axes.mT[:, None, :2] @ body_axes).abs() * state[..., None, 7:10]).sum(-1)
    depth = coordinates[..., 2:3].clamp(min=0.05) * math.tan(math.radians(FOVY) / 2)
    return torch.cat([coordinates, image_plane(coordinates), extents / depth], dim=-1)


def _rotations(state: torch.Tensor) -> torch.Tensor:
    """Each object's rotation [B, S, 3, 3]; an object with no orientation reads as upright."""
    return _rotation(state[..., 3:7])


def world_half_extents(state: torch.Tensor) -> torch.Tensor:
    """Half-extents [..., 3] along the world axes of each object's box, as rotated: its
    axis-aligned bounding box about its centre."""
    return (_rotations(state).abs() * state[..., None, 7:10]).sum(-1)


def lowest_point(state: torch.Tensor) -> torch.Tensor:
    """Height [...] of the lowest point of each object's box above the floor (z = 0)."""
    return state[..., 2] - world_half_extents(state)[..., 2]


def on_or_above_floor(state: torch.Tensor) -> torch.Tensor:
    """``state`` [..., 13] with every object raised, where needed, so that its box's lowest
    point is on or above the floor (z = 0): the floor is seen in every scene and nothing rests
    below it, so a hidden object's predicted fall ends there."""
    height = state[..., 2] - lowest_point(state).clamp(max=0.0)
    return torch.cat([state[..., :2], height[..., None], state[..., 3:]], dim=-1)


def quaternion_product(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
    """The rotation [..., 4] that applies ``second``, then ``first`` (w, x, y, z)."""
    w1, x1, y1, z1 = first.unbind(-1)
    w2, x2, y2, z2 = second.unbind(-1)
    return torch.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        dim=-1,
    )


def _unit_quaternion(state: torch.Tensor) -> torch.Tensor:
    """Each object's orientation [..., 4] scaled to unit length (zeros stay near zero)."""
    quaternion = state[..., 3:7]
    return cast(torch.Tensor, quaternion / quaternion.norm(dim=-1, keepdim=True).clamp(min=1e-6))


def _resting_face(rotation: torch.Tensor, half: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The box axis [..., 1] an object comes to rest on, the one furthest inside its tipping
    angle (tilted less than the angle at which the centre passes over the box's narrowest
    edge), and that axis [..., 3] in the world, pointing up."""
    narrowest_other = torch.stack(
        [half[..., [1, 2]].amin(-1), half[..., [0, 2]].amin(-1), half[..., [0, 1]].amin(-1)], dim=-1
    )
    tipping = torch.atan2(narrowest_other, half)
    tilt = torch.acos(rotation[..., 2, :].abs().clamp(max=1.0))
    nearest = (tipping - tilt).argmax(-1, keepdim=True)
    axis = rotation.gather(-1, nearest[..., None, :].expand(*rotation.shape[:-1], 1))[..., 0]
    return nearest, axis * torch.where(axis[..., 2:] < 0, -1.0, 1.0)


def _upright(quaternion: torch.Tensor) -> torch.Tensor:
    """The same rotation with w >= 0, as observed states have it."""
    return quaternion * torch.where(quaternion[..., :1] < 0, -1.0, 1.0)


def lying_on_floor(state: torch.Tensor) -> torch.Tensor:
    """``state`` [..., 13] with every object turned, by the smallest rotation, onto the face
    of its box it would topple onto (``_resting_face``), and set down on the floor there: where
    a tilted box that lands comes to rest (a plank falling steeply turns flat within one frame
    interval, so no extrapolation of its fall foresees it): a cube settles on its nearest face,
    a steep plank flat, not on its end. Its place along the floor is kept; an object with no
    orientation is only set down."""
    quaternion = _unit_quaternion(state)
    rotation = _rotations(torch.cat([state[..., :3], quaternion, state[..., 7:]], dim=-1))
    half = state[..., 7:10]
    nearest, axis = _resting_face(rotation, half)
    # the half-way quaternion turns the axis onto +z: (1 + a.z, a x z), normalised
    ax, ay, az = axis.unbind(-1)
    turn = torch.stack([1 + az, ay, -ax, torch.zeros_like(az)], dim=-1)
    turned = _upright(quaternion_product(turn / turn.norm(dim=-1, keepdim=True), quaternion))
    height = half.gather(-1, nearest)
    return torch.cat([state[..., :2], height, turned, state[..., 7:]], dim=-1)


def support_tops(belief: torch.Tensor, shape: torch.Tensor) -> torch.Tensor:
    """Height [B, S] at which what lands on each object rests: the top of its box, an open
    container's (``compound``) bottom, since what falls over its rim falls into it."""
    own = world_half_extents(belief)
    bottom = belief[..., 2] - own[..., 2]
    compound = (shape.argmax(-1) == COMPOUND) & (shape.amax(-1) > 0)
    wall = torch.minimum(belief[..., 7:10].amin(-1), torch.full_like(bottom, WALL))
    return torch.where(compound, bottom + 2 * wall, belief[..., 2] + own[..., 2])


def _rotate(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Quaternions [..., 4] turning by ``angle`` [...] about unit ``axis`` [..., 3]."""
    return torch.cat(
        [torch.cos(angle / 2)[..., None], axis * torch.sin(angle / 2)[..., None]], dim=-1
    )


def _dot(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
    return (first * second).sum(-1)


def pivoted_down(
    state: torch.Tensor, belief: torch.Tensor, shape: torch.Tensor, known: torch.Tensor
) -> torch.Tensor:
    """``state`` [B, S, 13] with each object turned about the lowest corner of its box, the way
    it would topple (onto ``_resting_face``), until its underside meets the top of another
    known object at its ``belief`` (``support_tops``; nine points of each top: the corners and
    middles of its world box's top and its centre), else lying flat on the floor: where a plank
    whose front edge has landed comes to rest, propped on an object it falls back onto, or
    flat. An object already on another's top stays where it is. The turn is found without
    gradient; the pose passes gradients to ``state``'s position and orientation."""
    quaternion = _unit_quaternion(state)
    centre, half = state[..., :3], state[..., 7:10]
    rotation = _rotations(torch.cat([centre, quaternion, half], dim=-1))
    corner = torch.where(rotation[..., 2, :] > 0, -1.0, 1.0) * half  # the lowest, box frame
    hinge = centre + (rotation * corner[..., None, :]).sum(-1)  # [B, S, 3]
    with torch.no_grad():
        nearest, up = _resting_face(rotation, half)
        thickness = half.gather(-1, nearest)[..., 0]  # the underside's half-thickness [B, S]
        vertical = torch.zeros_like(up)
        vertical[..., 2] = 1.0
        across = torch.linalg.cross(up, vertical)  # the hinge line's direction
        tilt = torch.atan2(across.norm(dim=-1), up[..., 2])
        across = across / across.norm(dim=-1, keepdim=True).clamp(min=1e-6)
        along = torch.linalg.cross(across, up)  # in the underside, away from the hinge line
        face = centre - thickness[..., None] * up - hinge  # underside's centre from hinge
        along = along * torch.where(_dot(face, along)[..., None] < 0, -1.0, 1.0)
        outward = torch.linalg.cross(vertical, across)  # horizontal, away from the hinge line
        outward = outward * torch.where(_dot(centre - hinge, outward)[..., None] < 0, -1.0, 1.0)
        others = 1.0 - F.one_hot(nearest[..., 0], 3).to(half)  # the underside's two axes
        reach = [
            (_dot(rotation.transpose(-1, -2), d[..., None, :]).abs() * half * others).sum(-1)
            for d in (across, along)
        ]
        # the nine top points of every other object [B, S, 9, 3], from each hinge [B, S, S, 9, 3]
        grid = torch.tensor([-1.0, 0.0, 1.0], dtype=state.dtype, device=state.device)
        offsets = torch.stack(torch.meshgrid(grid, grid, indexing="ij"), -1).reshape(9, 2)
        extents = world_half_extents(belief)
        points = torch.cat(
            [
                belief[..., None, :2] + offsets * extents[..., None, :2],
                support_tops(belief, shape)[..., None, None].expand(-1, -1, 9, 1),
            ],
            dim=-1,
        )
        relative = points[:, None] - hinge[:, :, None, None]

        def per_pair(values: torch.Tensor) -> torch.Tensor:  # [B, S, ...] -> [B, S, 1, 1, ...]
            return values[:, :, None, None]

        side = _dot(relative, per_pair(across)) - per_pair(_dot(face, across))
        height, out = relative[..., 2], _dot(relative, per_pair(outward))
        distance = torch.hypot(out, height) - per_pair(_dot(face, along))
        depth = _dot(relative, per_pair(up))  # above (+) or below (-) the underside
        met = (
            (side.abs() <= per_pair(reach[0]))
            & (distance.abs() <= per_pair(reach[1]))
            & (height > 0)
            & (out > 0)
            & (depth <= per_pair(2 * thickness) + REST_TOLERANCE)
            & known[:, None, :, None]
            & ~torch.eye(known.shape[1], dtype=torch.bool, device=known.device)[..., None]
        )
        slope = torch.where(depth >= 0, per_pair(tilt), torch.atan2(height, out))
        rest = (
            torch.where(met, slope.clamp(max=per_pair(tilt)), torch.zeros_like(slope))
            .amax(-1)
            .amax(-1)
        )
        turn = _rotate(across, tilt - rest)
        propped = met.any(-1).any(-1)
    turned = hinge + (quaternion_matrix(turn) * (centre - hinge)[..., None, :]).sum(-1)
    turned = torch.cat(
        [turned[..., :2], torch.where(propped, turned[..., 2], thickness)[..., None]], dim=-1
    )
    return torch.cat(
        [turned, _upright(quaternion_product(turn, quaternion)), half, state[..., 10:]], dim=-1
    )


def sample_points(state: torch.Tensor, shape: torch.Tensor) -> torch.Tensor:
    """The tested points of each object [B, S, 9, 3] (world): its centre and the corners of its
    box drawn in (CORNER_INSET), and for a round shape further, into the shape itself (a
    sphere's box corners stick out of it)."""
    signs = torch.tensor(
        [[0.0, 0.0, 0.0]]
        + [[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)],
        dtype=state.dtype,
        device=state.device,
    )
    inset = CORNER_INSET / torch.tensor(ROUNDNESS, dtype=state.dtype, device=state.device)
    inset = (shape * inset).sum(-1, keepdim=True) + CORNER_INSET * (
        shape.sum(-1, keepdim=True) == 0
    )
    local = signs * (inset * state[..., 7:10])[..., None, :]  # [B, S, 9, 3]
    return state[..., None, :3] + torch.einsum("bsij,bspj->bspi", _rotations(state), local)


def occluder_boxes(state: torch.Tensor, shape: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Each object as up to five solid boxes in its own frame: a solid object is its bounding
    box; an open container (``compound``) its bottom and four walls. Returns the boxes' centres
    and half-sizes [B, S, 5, 3] (body frame, from the object's centre) and whether each is
    real [B, S, 5]."""
    half = state[..., 7:10]
    hx, hy, hz = half.unbind(-1)
    wall = torch.minimum(half.amin(-1), torch.full_like(hx, WALL))
    zero = torch.zeros_like(hx)
    centres = torch.stack(
        [
            torch.stack([zero, zero, -hz + wall], -1),
            torch.stack([zero, hy - wall, zero], -1),
            torch.stack([zero, wall - hy, zero], -1),
            torch.stack([hx - wall, zero, zero], -1),
            torch.stack([wall - hx, zero, zero], -1),
        ],
        dim=-2,
    )
    halves = torch.stack(
        [
            torch.stack([hx, hy, wall], -1),
            torch.stack([hx, wall, hz], -1),
            torch.stack([hx, wall, hz], -1),
            torch.stack([wall, hy, hz], -1),
            torch.stack([wall, hy, hz], -1),
        ],
        dim=-2,
    )
    compound = (shape.argmax(-1) == COMPOUND) & (shape.amax(-1) > 0)  # [B, S]
    solid_centres = torch.zeros_like(centres)
    solid_halves = torch.cat([half[..., None, :], torch.zeros_like(halves[..., 1:, :])], -2)
    real = compound[..., None] | (torch.arange(5, device=compound.device) == 0)  # solid: 1 box
    return (
        torch.where(compound[..., None, None], centres, solid_centres),
        torch.where(compound[..., None, None], halves, solid_halves),
        real,
    )


def sight_blocked(
    eye: torch.Tensor, points: torch.Tensor, state: torch.Tensor, shape: torch.Tensor
) -> torch.Tensor:
    """How surely each object j's boxes block the sight line from ``eye`` [B, 3] to each point
    [B, S, P, 3] [B, S, P, S_j] (soft, in [0, 1]): a slab test in each box's frame, softened
    by SOFTNESS over how far the line runs through the box before reaching the point."""
    rotation = _rotations(state)  # [B, J, 3, 3]
    centres, halves, real = occluder_boxes(state, shape)  # [B, J, Q, 3], [B, J, Q]
    world_centres = state[..., None, :3] + torch.einsum("bjik,bjqk->bjqi", rotation, centres)
    # eye and points in each box's frame: [B, J, Q, 3] and [B, S, P, J, Q, 3]
    eye_local = torch.einsum("bjki,bjqk->bjqi", rotation, eye[:, None, None] - world_centres)
    offset = points[:, :, :, None, None] - world_centres[:, None, None]
    point_local = torch.einsum("bjki,bspjqk->bspjqi", rotation, offset)
    direction = point_local - eye_local[:, None, None]
    length = direction.norm(dim=-1).clamp(min=1e-6)
    tiny = direction.abs() < 1e-9
    safe = torch.where(tiny, torch.full_like(direction, 1e-9), direction)
    start = eye_local[:, None, None]
    low, high = (-halves[:, None, None] - start) / safe, (halves[:, None, None] - start) / safe
    inside_slab = start.abs() <= halves[:, None, None]
    enter = torch.where(tiny, torch.where(inside_slab, -1e9, 1e9), torch.minimum(low, high))
    leave = torch.where(tiny, torch.where(inside_slab, 1e9, -1e9), torch.maximum(low, high))
    near, far = enter.amax(-1) * length, leave.amin(-1) * length  # metres along the line
    # the stretch of the line inside the box, up to the point: > 0 when the box hides it
    through = torch.sigmoid((torch.minimum(far, length) - near.clamp(min=0)) / SOFTNESS)
    blocked = through * real[:, None, None].float()  # [B, S, P, J, Q]
    return 1 - (1 - blocked).prod(-1)


def seen_by_geometry(
    state: torch.Tensor, shape: torch.Tensor, known: torch.Tensor, camera: torch.Tensor
) -> torch.Tensor:
    """How likely each slot is to be seen by geometry alone [B, S], from the slots' states
    [B, S, 13] and shapes [B, S, SHAPES] at poses [B, 6]: whether some of its image box is in
    the frame, times the best, over the tested points of its box, of the chance that the point
    is above the floor and hidden by no other known slot. What a renderer of the objects' boxes
    would say."""
    seen_as = view(state, camera)
    centre, half = seen_as[..., 3:5], seen_as[..., 5:7]
    overlap = torch.minimum(centre + half, torch.ones_like(centre)) - torch.maximum(
        centre - half, -torch.ones_like(centre)
    )
    in_frame = torch.sigmoid(overlap / (2 * SOFTNESS)).prod(-1)
    in_frame = in_frame * torch.sigmoid((seen_as[..., 2] - 0.05) / SOFTNESS)  # before the eye
    points = sample_points(state, shape)  # [B, S, P, 3]
    above_floor = torch.sigmoid(points[..., 2] / SOFTNESS)
    blocked = sight_blocked(camera_axes(camera)[0], points, state, shape)  # [B, S, P, J]
    slots = known.shape[1]
    others = known[:, None, :] & ~torch.eye(slots, dtype=torch.bool, device=known.device)
    clear = (1 - blocked * others[:, :, None].float()).prod(-1)
    return in_frame * (above_floor * clear).amax(-1)


def draw_ellipses(
    state: torch.Tensor, opacity: torch.Tensor, camera: torch.Tensor, image_size: tuple[int, int]
) -> torch.Tensor:
    """Object states [B, T, S, 13] drawn as ellipses of their colour on grey [B, T, 3, H, W],
    each filling the image-plane bounding box of the object's box as it is turned (``view``):
    a rod seen side-on is a thin streak, not a disc as long as the rod. ``opacity`` [B, T, S]
    in [0, 1]; painted far to near."""
    batch, steps, slots = state.shape[:3]
    seen_as = view(state.flatten(0, 1), camera.flatten(0, 1)).view(batch, steps, slots, VIEW)
    return paint_ellipses(
        seen_as[..., 3:5],
        seen_as[..., 5:7],
        state[..., 10:13],
        opacity,
        seen_as[..., 2],
        image_size,
    )


def paint_ellipses(
    centre: torch.Tensor,
    half: torch.Tensor,
    colour: torch.Tensor,
    opacity: torch.Tensor,
    depth: torch.Tensor,
    image_size: tuple[int, int],
) -> torch.Tensor:
    """Ellipses on grey [B, T, 3, H, W], one per slot, each filling its image-plane box
    (``centre`` and ``half``-extents [B, T, S, 2], ``view``'s units) in its ``colour``
    [B, T, S, 3], as opaque as ``opacity`` [B, T, S], painted far to near (``depth``
    [B, T, S])."""
    batch, steps, slots = centre.shape[:3]
    height, width = image_size
    focal = height / 2  # the image plane's [-1, 1] across the field of view, in pixels
    column = width / 2 + centre[..., 0] * focal
    row = height / 2 - centre[..., 1] * focal
    # half a pixel at least, so that a thin object still shows
    half_width, half_height = (half * focal).clamp(min=0.5).unbind(-1)
    rows = torch.arange(height, device=centre.device, dtype=torch.float32) + 0.5
    columns = torch.arange(width, device=centre.device, dtype=torch.float32) + 0.5
    image = torch.full((batch, steps, 3, height, width), 0.5, device=centre.device)
    order = depth.argsort(dim=-1, descending=True)
    for index in range(slots):
        slot = order[..., index]  # [B, T]: the farthest remaining slot of each frame

        def take(values: torch.Tensor, slot: torch.Tensor = slot) -> torch.Tensor:
            return values.gather(2, slot[..., None]).squeeze(2)

        inside = (
            ((rows[:, None] - take(row)[..., None, None]) / take(half_height)[..., None, None]).pow(
                2
            )
            + (
                (columns[None] - take(column)[..., None, None]) / take(half_width)[..., None, None]
            ).pow(2)
            <= 1
        ).float()
        alpha = (inside * take(opacity)[..., None, None])[:, :, None]
        image = image * (1 - alpha) + take_colour(colour, slot)[..., None, None] * alpha
    return image.clamp(0, 1)


def take_colour(colour: torch.Tensor, slot: torch.Tensor) -> torch.Tensor:
    """Each frame's ``slot`` [B, T] of ``colour`` [B, T, S, 3]: [B, T, 3]."""
    return colour.gather(2, slot[..., None, None].expand(-1, -1, 1, 3))[:, :, 0]
