"""The positive control's geometry (``model/object_geometry.py``): sight lines against object
boxes, with open containers seen into over their rims, agree with what MuJoCo renders."""

import mujoco
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from voe_lightning import scenes, specs
from voe_lightning.model.object_state.geometry import (
    draw_ellipses,
    lying_on_floor,
    on_or_above_floor,
    pivoted_down,
    quaternion_matrix,
    seen_by_geometry,
)

CAMERA = torch.tensor([[0.0, 0.0, 0.4, 3.0, 90.0, -30.0]])  # looking along +y, from above
BOX, COMPOUND = specs.OBJECT_SHAPES.index("box"), specs.OBJECT_SHAPES.index("compound")


def states(*objects: tuple[tuple[float, float, float], tuple[float, float, float], int]):
    """A batch of one scene: (centre, half-size, shape) per object -> state [1, S, 13], shape
    one-hot [1, S, SHAPES], every slot known."""
    state = torch.zeros(1, len(objects), 13)
    for index, (centre, half, _) in enumerate(objects):
        state[0, index, :3], state[0, index, 3], state[0, index, 7:10] = (
            torch.tensor(centre),
            1.0,
            torch.tensor(half),
        )
    shape = F.one_hot(torch.tensor([[label for *_, label in objects]]), len(specs.OBJECT_SHAPES))
    return state, shape.float(), torch.ones(1, len(objects), dtype=torch.bool)


def test_quaternion_matrices_are_mujocos_and_a_missing_orientation_is_none():
    """The geometry's rotation (one matrix product of a quaternion's pairwise products) is
    MuJoCo's own ``mju_quat2Mat`` for unit quaternions; an absent slot's zeros give zeros."""
    quaternions = torch.randn(
        64, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64
    )
    quaternions = quaternions / quaternions.norm(dim=-1, keepdim=True)
    expected = np.empty((64, 9))
    for quaternion, matrix in zip(quaternions.numpy(), expected):
        mujoco.mju_quat2Mat(matrix, quaternion)
    np.testing.assert_allclose(
        quaternion_matrix(quaternions).flatten(1).numpy(), expected, atol=1e-12
    )
    assert torch.equal(quaternion_matrix(torch.zeros(2, 4)), torch.zeros(2, 3, 3))


@pytest.mark.parametrize("height, seen", [(0.15, False), (0.75, True)])
def test_an_open_container_hides_what_sinks_below_its_rim_and_shows_what_protrudes(height, seen):
    container = ((0.0, 0.0, 0.35), (0.5, 0.35, 0.35), COMPOUND)
    block = ((0.0, 0.0, 0.05 + height / 2), (0.15, 0.1, height / 2), BOX)
    p = seen_by_geometry(*states(block, container), CAMERA)[0, 0]
    assert (p > 0.5) == seen, float(p)


def test_a_solid_box_hides_what_is_behind_it_not_what_is_in_front_or_beside():
    screen = ((0.0, 0.0, 0.4), (0.4, 0.05, 0.4), BOX)
    behind = ((0.0, 0.6, 0.15), (0.1, 0.1, 0.1), BOX)
    in_front = ((0.0, -0.6, 0.15), (0.1, 0.1, 0.1), BOX)
    beside = ((1.0, 0.6, 0.15), (0.1, 0.1, 0.1), BOX)
    p = seen_by_geometry(*states(behind, in_front, beside, screen), CAMERA)[0]
    assert p[0] < 0.05 and p[1] > 0.95 and p[2] > 0.95 and p[3] > 0.95, p


def test_what_the_control_expected_is_drawn_as_each_object_looks_turned():
    """A rod lying across the view is drawn as a streak about as wide as the rod and a few
    pixels high, not as a disc as large as its length; a cube as a round blob."""
    rod = ((0.0, 0.0, 0.03), (0.8, 0.03, 0.03), BOX)
    cube = ((0.0, 1.5, 0.2), (0.2, 0.2, 0.2), BOX)
    state, _, _ = states(rod, cube)
    red, blue = torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 1.0])
    state[0, 0, 10:13], state[0, 1, 10:13] = red, blue
    image = draw_ellipses(state[:, None], torch.ones(1, 1, 2), CAMERA[:, None], (64, 64))[0, 0]

    def extent(colour: torch.Tensor) -> tuple[int, int]:
        """Columns and rows with a pixel of exactly that colour."""
        painted = (image - colour[:, None, None]).abs().amax(0) < 1e-6
        return int(painted.any(0).sum()), int(painted.any(1).sum())

    columns, rows = extent(red)
    assert columns >= 30 and rows <= 4, (columns, rows)
    columns, rows = extent(blue)
    assert columns >= 4 and 0.6 <= rows / columns <= 1.6, (columns, rows)


def test_below_the_floor_is_unseen_and_geometry_passes_gradients_to_positions():
    state, shape, known = states(
        ((0.0, 0.0, -0.5), (0.1, 0.1, 0.1), BOX), ((0.0, 0.0, 0.0), (0.1, 0.1, 0.1), BOX)
    )
    state.requires_grad_(True)
    p = seen_by_geometry(state, shape, known, CAMERA)
    assert p[0, 0] < 0.05 and p[0, 1] > 0.95
    p[0, 1].backward()
    assert torch.isfinite(state.grad).all() and state.grad[0, 1, 2] != 0


@pytest.mark.parametrize("concept", ["solidity", "containment", "continuity"])
def test_geometry_of_the_true_states_agrees_with_the_rendered_masks(concept):
    """Every object of two rendered probe pairs per variant, every frame: the geometry of the
    true states (hidden objects included) says seen exactly where the mask shows the object,
    but for slivers (under 0.5% of the frame)."""
    agree = total = 0
    for variant in specs.STANDARD_VARIANTS[concept]:
        for seed in (0, 1):
            record = scenes.generate_probe(concept, variant, seed)
            for side in ("consistent", "inconsistent"):
                objects = record[side, "objects"]
                label = objects["shape_label"].long()
                state = torch.cat(
                    [
                        objects["position"],
                        objects["orientation"],
                        objects["size"],
                        objects["color"],
                    ],
                    dim=-1,
                ).float()
                shape = F.one_hot(label, len(specs.OBJECT_SHAPES)).float()
                present = label > 0
                camera = record["camera"].float().reshape(-1, 6).expand(len(state), 6)
                p = seen_by_geometry(state, shape, present, camera)
                fraction = objects["visible_fraction"]
                clear = present & ((fraction == 0) | (fraction > 0.005))
                agree += int(((p > 0.5) == (fraction > 0))[clear].sum())
                total += int(clear.sum())
    assert agree / total > 0.98, f"{agree} of {total}"


def test_nothing_is_predicted_below_the_floor():
    """A box whose centre would sink below its half-height is raised to rest on the floor, a
    tilted one by its tilted extent; an object above the floor is left where it is."""
    state, _, _ = states(
        ((0.0, 0.0, -0.8), (0.1, 0.2, 0.3), BOX), ((0.5, 0.0, 1.2), (0.1, 0.1, 0.1), BOX)
    )
    tilted = state.clone()
    tilted[0, 0, 3:7] = torch.tensor([0.9238795, 0.3826834, 0.0, 0.0])  # 45 degrees about x
    for given, lowest in ((state, 0.3), (tilted, (0.2 + 0.3) * 0.70710678)):
        raised = on_or_above_floor(given)
        assert float(raised[0, 0, 2]) == pytest.approx(lowest, abs=1e-5)
        torch.testing.assert_close(raised[0, 1], given[0, 1])
        torch.testing.assert_close(
            raised[..., [0, 1, *range(3, 13)]], given[..., [0, 1, *range(3, 13)]]
        )


def _dropped(
    half: tuple[float, float, float], tilt: float, yaw: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """A box of half-sizes ``half`` tilted ``tilt`` degrees about its x axis, yawed ``yaw``,
    released with its lowest corner 1 cm above a floor: its state then and after MuJoCo has
    let it fall and come to rest (3 s), each [13]."""
    quat, turn, orientation = np.empty(4), np.empty(4), np.empty(4)
    mujoco.mju_axisAngle2Quat(quat, np.array([1.0, 0.0, 0.0]), np.deg2rad(tilt))
    mujoco.mju_axisAngle2Quat(turn, np.array([0.0, 0.0, 1.0]), np.deg2rad(yaw))
    mujoco.mju_mulQuat(orientation, turn, quat)
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[5, 5, 0.1])
    body = spec.worldbody.add_body(name="box", quat=orientation)
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half), friction=[1.0, 0.005, 0.0001])
    model = spec.compile()
    data = mujoco.MjData(model)
    rotation = np.empty(9)
    mujoco.mju_quat2Mat(rotation, orientation)
    data.qpos[2] = np.abs(rotation.reshape(3, 3)[2]) @ np.array(half) + 0.01
    mujoco.mj_forward(model, data)

    def state() -> torch.Tensor:
        quat = data.qpos[3:7] * (1 if data.qpos[3] >= 0 else -1)
        return torch.tensor([*data.qpos[:3], *quat, *half, 0.5, 0.5, 0.5], dtype=torch.float64)

    released = state()
    while data.time < 3.0:
        mujoco.mj_step(model, data)
    return released, state()


@pytest.mark.parametrize(
    "half, tilt",
    [
        ((0.8, 1.2, 0.03), 60.0),
        ((0.8, 1.2, 0.03), 75.0),
        ((0.2, 0.2, 0.2), 25.0),
        ((0.2, 0.2, 0.2), 65.0),
        ((0.1, 0.1, 0.1), 0.0),
    ],
)
def test_a_landing_box_comes_to_rest_as_lying_on_floor_lays_it(half, tilt):
    """What MuJoCo does with a tilted box dropped onto the floor: a steep plank falls flat (not
    onto its end), a cube tilted less than 45 degrees settles back on that face and one tilted
    more topples onto the next; ``lying_on_floor`` of the released state gives the height and
    the orientation it rests at (up to the yaw the landing adds)."""
    released, rest = _dropped(half, tilt, yaw=30.0)
    laid = lying_on_floor(released)
    assert float(laid[2]) == pytest.approx(float(rest[2]), abs=2e-3)
    up_laid, up_rest = (torch.from_numpy(_matrix(state[3:7]))[2] for state in (laid, rest))
    torch.testing.assert_close(up_laid.abs(), up_rest.abs(), atol=0.02, rtol=0)
    torch.testing.assert_close(laid[7:], released[7:])
    assert float(laid[3:7].norm()) == pytest.approx(1.0)


def _matrix(quaternion: torch.Tensor) -> np.ndarray:
    matrix = np.empty(9)
    mujoco.mju_quat2Mat(matrix, quaternion.numpy())
    return matrix.reshape(3, 3)


def _pitched_plank(pitch: float, half=(0.6, 1.2, 0.03)) -> torch.Tensor:
    """A plank's state [13] pitched ``pitch`` degrees about x (its +y end up), its lowest edge
    on the floor along the x axis from (0, 0, 0) to (-1.2, 0, 0)."""
    angle = np.deg2rad(pitch)
    centre = (
        -half[0],
        half[1] * np.cos(angle) - half[2] * np.sin(angle),
        half[1] * np.sin(angle) + half[2] * np.cos(angle),
    )
    return torch.tensor(
        [*centre, np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0, *half, 0.5, 0.5, 0.5],
        dtype=torch.float32,
    )


def _pitch(state: torch.Tensor) -> float:
    matrix = _matrix(state[3:7].double())
    return float(np.degrees(np.arctan2(matrix[2, 1], matrix[1, 1])))


@pytest.mark.parametrize("near_edge", [0.6, 1.25])
def test_a_plank_pivots_onto_what_is_believed_below_it(near_edge):
    """``pivoted_down``: a plank whose front edge has landed turns about it until its underside
    meets the nearest top edge of a cube believed under it (pitch atan(top / distance)), and
    falls flat onto the floor, swinging out from the edge, once the cube is forgotten; a cube
    beside the plank and one above it hold nothing up."""
    plank = _pitched_plank(40.0)
    state, shape, known = states(
        ((0.0, 0.0, 0.0), (0.1, 0.1, 0.1), BOX),
        ((-0.6, near_edge + 0.25, 0.25), (0.25, 0.25, 0.25), BOX),
        ((3.0, 1.0, 0.25), (0.25, 0.25, 0.25), BOX),  # beside
        ((-0.6, 0.6, 2.5), (0.2, 0.2, 0.2), BOX),
    )  # above
    state[0, 0] = plank
    turned = pivoted_down(state, state, shape, known)[0, 0]
    assert _pitch(turned) == pytest.approx(np.degrees(np.arctan2(0.5, near_edge)), abs=0.1)
    torch.testing.assert_close(turned[7:], plank[7:])
    known[0, 1] = False
    flat = pivoted_down(state, state, shape, known)[0, 0]
    assert _pitch(flat) == pytest.approx(0.0, abs=0.1)
    torch.testing.assert_close(flat[:3], torch.tensor([-0.6, 1.2, 0.03]), atol=1e-4, rtol=0)


def test_a_pivoting_plank_comes_to_rest_as_mujoco_rests_object_persistence_planks():
    """The positive control's support rule against the simulator: in object persistence's
    standard probes, the plank at the manipulation frame (front edge landed, the object
    hidden) turned by ``pivoted_down`` onto the object as last seen lands where MuJoCo props it
    (height within 0.12 m; the plank lying flat in place would be 0.3 m and more off), and with
    the object forgotten, flat where MuJoCo lays it once the object has vanished."""
    for seed in range(3):
        record = scenes.generate_probe("object_persistence", "standard", seed)
        frame = int(record["manipulation_frame"])
        sides = {}
        for side in ("consistent", "inconsistent"):
            objects = record[side, "objects"]
            sides[side] = torch.cat(
                [objects["position"], objects["orientation"], objects["size"], objects["color"]],
                dim=-1,
            ).float()
        objects = record["consistent", "objects"]
        plank = int(objects["size"][0].amax(-1).argmax())
        hidden = int(record["manipulated_ids"][0])  # slots are indexed by mask id
        shown = [plank, hidden]
        state = torch.stack([sides["consistent"][frame, plank], sides["consistent"][0, hidden]])[
            None
        ]
        shape = F.one_hot(
            objects["shape_label"][0, shown].long()[None], len(specs.OBJECT_SHAPES)
        ).float()
        known = torch.ones(1, 2, dtype=torch.bool)
        propped = pivoted_down(state, state, shape, known)[0, 0]
        rest = sides["consistent"][-1, plank]
        assert abs(float(propped[2] - rest[2])) < 0.12, (seed, propped[:3], rest[:3])
        assert float(lying_on_floor(state[0, 0])[2] - rest[2]) < -0.3
        known[0, 1] = False
        flat = pivoted_down(state, state, shape, known)[0, 0]
        lying = sides["inconsistent"][-1, plank]
        assert abs(float(flat[2] - lying[2])) < 0.01, (seed, flat[:3], lying[:3])
