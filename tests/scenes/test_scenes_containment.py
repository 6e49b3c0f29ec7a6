"""Containment scenes: the cube really rides in the sliding container, the rod comes down
from above, the counterbalanced probe is the other half of the standard one's quadruplet, probes
share the examples' camera and parameter ranges, and the controls and examples differ from the
probes the way the paper says."""

import numpy as np
import pytest
import torch

from voe_lightning.scenes import containment, generate_clip, generate_probe
from voe_lightning.scenes.camera import CameraPose, VideoOptions
from voe_lightning.scenes.sampling import RejectedSample, rng_for

VIDEO = VideoOptions()
#: A pose in the middle of the concept's camera range.
CAMERA = CameraPose(lookat=(0.0, 0.2, 0.35), distance=3.4, azimuth=90.0, elevation=-27.0)
CONTAINER, CUBE, ROD = 1, 2, 3  # mask ids in the order the scene adds them


def centroid_column(mask: torch.Tensor, object_id: int) -> float:
    return float(torch.nonzero(mask == object_id)[:, 1].float().mean())


@pytest.fixture(scope="module")
def probe_record():
    return generate_probe("containment", "standard", 3)


def test_container_is_one_object_of_five_boxes():
    rng = np.random.default_rng(0)
    layout, _ = containment.sample_layout(rng, VIDEO, containment.PROBE_RANGES)
    sim = containment.build(rng, VIDEO, CAMERA, layout)
    geoms = sim.objects["container"].geom_names
    assert len(geoms) == 5
    assert {int(sim.geom_mask_id[sim.model.geom(g).id]) for g in geoms} == {CONTAINER}


def test_cube_rides_along_in_the_sliding_container():
    rng = np.random.default_rng(4)
    layout, frame = containment.sample_layout(rng, VIDEO, containment.PROBE_RANGES)
    sim = containment.build(rng, VIDEO, CAMERA, layout)
    sim.step(frame * VIDEO.steps_per_frame)
    resting = sim.position("cube")
    on_bottom = containment.WALL + layout.cube_half
    assert resting[2] == pytest.approx(on_bottom, abs=0.01), "the cube rests on the bottom"
    sim.step((VIDEO.num_frames - frame) * VIDEO.steps_per_frame)
    container_moved = sim.position("container")[0] - layout.container_xy[0]
    assert container_moved == pytest.approx(layout.shift, abs=0.02)
    carried = sim.position("cube") - resting
    assert carried[0] == pytest.approx(layout.shift, abs=layout.half_x), "the cube moves with it"


def test_inconsistent_probe_reveals_the_cube_where_the_container_was(probe_record):
    m = int(probe_record["manipulation_frame"])
    consistent, inconsistent = probe_record["consistent"], probe_record["inconsistent"]
    start = centroid_column(consistent["mask"][m], CONTAINER)
    end = centroid_column(consistent["mask"][-1], CONTAINER)
    assert abs(end - start) > 8, "the container slides well across the view"
    assert (inconsistent["mask"][-1] == CUBE).sum() > 10, "the cube is revealed"
    revealed = centroid_column(inconsistent["mask"][-1], CUBE)
    assert abs(revealed - start) < abs(revealed - end), "left where the container was"
    assert (consistent["mask"][-1] == CUBE).sum() < (inconsistent["mask"][-1] == CUBE).sum()
    # The container and rod move identically in both videos; only the cube differs.
    for object_id in (CONTAINER, ROD):
        cons, inc = consistent["mask"][-1] == object_id, inconsistent["mask"][-1] == object_id
        assert (cons & ~inc).sum() <= (inconsistent["mask"][-1] == CUBE).sum()


@pytest.fixture(scope="module")
def counterbalanced_record():
    return generate_probe("containment", "counterbalanced", 3)


def test_counterbalanced_consistent_reveals_the_cube_behind_inconsistent_carries_it(
    counterbalanced_record,
):
    m = int(counterbalanced_record["manipulation_frame"])
    consistent = counterbalanced_record["consistent", "mask"]
    inconsistent = counterbalanced_record["inconsistent", "mask"]
    assert (consistent[0] == CUBE).any(), "the cube is seen falling"
    assert not (consistent[m] == CUBE).any(), "it lies hidden behind the container"
    assert (consistent[-1] == CUBE).sum() > 10, "consistent: the sliding container reveals it"
    assert (inconsistent[m + 1 :] == CUBE).sum() <= 2, "inconsistent: it is never revealed"
    start = centroid_column(consistent[m], CONTAINER)
    end = centroid_column(consistent[-1], CONTAINER)
    revealed = centroid_column(consistent[-1], CUBE)
    assert abs(revealed - start) < abs(revealed - end), "revealed where the container was"
    for object_id in (CONTAINER, ROD):  # the container and rod move identically in both videos
        assert torch.equal(consistent[-1] == object_id, inconsistent[-1] == object_id)


def test_counterbalanced_mirrors_the_standard_foreground_cue():
    """The standard inconsistent video shows the cube the consistent one hides, the
    counterbalanced one hides the cube the consistent one shows, by exactly as much (one
    quadruplet: after the change each inconsistent video is the other's consistent one)."""
    differences = {}
    for variant in ("standard", "counterbalanced"):
        per_pair = []
        for seed in range(6):
            record = generate_probe("containment", variant, seed)
            m = int(record["manipulation_frame"])
            visible = [
                int((record[side, "mask"][m + 1 :] > 0).sum())
                for side in ("inconsistent", "consistent")
            ]
            per_pair.append(visible[0] - visible[1])
        differences[variant] = np.array(per_pair)
    assert (differences["standard"] > 0).all()
    assert np.array_equal(differences["counterbalanced"], -differences["standard"])


def test_every_kind_draws_its_camera_from_the_concept_range():
    for kind in ("example", "cube_behind_container", "cube_random_position"):
        cameras = {
            tuple(generate_clip("containment", kind, seed)["camera"][0].tolist())
            for seed in range(3)
        }
        assert len(cameras) == 3, f"{kind} uses a fixed camera"
        assert all(containment.CAMERA.contains(np.array(pose)) for pose in cameras)
    for variant in ("standard", "counterbalanced"):
        cameras = {
            tuple(generate_probe("containment", variant, seed)["camera"][0].tolist())
            for seed in range(3)
        }
        assert len(cameras) == 3, f"{variant} probes use a fixed camera"
        assert all(containment.CAMERA.contains(np.array(pose)) for pose in cameras)


def layout_parameters(layout, frame) -> dict[str, float]:
    """The free parameters of a drawn layout, including the rod's and container's timing."""
    return {
        "half_x": layout.half_x,
        "half_y": layout.half_y,
        "height": layout.height,
        "cube_half": layout.cube_half,
        "container_x": layout.container_xy[0],
        "container_y": layout.container_xy[1],
        "shift": abs(layout.shift),
        "drop": layout.cube_start[2] - layout.height,
        "frame": frame,
        "rod_down_start": layout.rod_down[0],
        "move_duration": layout.move_end - layout.move_start,
    }


def test_probe_parameters_lie_inside_the_examples_with_real_mass():
    """Examples are like probes, not constrained: every probe parameter (both halves of a
    quadruplet, and the behind control) falls in the examples' range, and at least
    15% of examples fall in each probe parameter's range."""
    assert containment.EXAMPLE_RANGES.contains(containment.PROBE_RANGES)
    assert containment.EXAMPLE_RANGES.contains(containment.BEHIND_RANGES)
    draws = {}
    for name, ranges in (
        ("example", containment.EXAMPLE_RANGES),
        ("standard", containment.PROBE_RANGES),
        ("behind", containment.BEHIND_RANGES),
    ):
        rng = np.random.default_rng(0)
        rows = [
            layout_parameters(*containment.sample_layout(rng, VIDEO, ranges)) for _ in range(600)
        ]
        draws[name] = {key: np.array([row[key] for row in rows]) for key in rows[0]}
    examples = draws["example"]
    for name in ("standard", "behind"):
        for key, values in draws[name].items():
            low, high = values.min(), values.max()
            assert examples[key].min() <= low and high <= examples[key].max(), (
                f"{name} {key} in [{low:.3f}, {high:.3f}] leaves the examples' "
                f"[{examples[key].min():.3f}, {examples[key].max():.3f}]"
            )
            mass = np.mean((examples[key] >= low) & (examples[key] <= high))
            assert mass >= 0.15, f"only {mass:.0%} of examples have {key} in {name}'s range"


def test_rod_descends_from_above_the_view(probe_record):
    masks = probe_record["consistent", "mask"]
    assert not (masks[0] == ROD).any(), "the rod starts out of view"
    last = masks[-1] == ROD
    assert last.any() and last[0].any(), "at the end it reaches down from the top edge"
    pixels = torch.nonzero(last)
    bottom = int(pixels[:, 0].max())
    columns = pixels[pixels[:, 0] == bottom, 1]
    below = masks[-1][bottom : bottom + 2, int(columns.min()) - 1 : int(columns.max()) + 2]
    assert (below == CONTAINER).any(), "the rod's lower end rests on the container's wall"


def test_cube_behind_container_is_hidden_then_revealed_in_place():
    record = generate_clip("containment", "cube_behind_container", 1)
    masks = record["mask"]
    seen = (masks == CUBE).flatten(1).any(1).numpy()
    assert seen[0], "the cube is seen falling"
    middle = VIDEO.num_frames // 2
    assert not seen[middle], "it lands hidden behind the container"
    assert seen[-1], "the sliding container reveals it"
    revealed = centroid_column(masks[-1], CUBE)
    start, end = centroid_column(masks[0], CONTAINER), centroid_column(masks[-1], CONTAINER)
    assert abs(revealed - start) < abs(revealed - end)


def test_cube_random_position_is_visible_outside_the_container():
    for seed in range(2):
        rng = rng_for(seed, "test")
        layout, _, _ = containment.clip_layout("cube_random_position", rng, VIDEO)
        x0, y0 = layout.container_xy
        cx, cy, _ = layout.cube_start
        assert abs(cx - x0) > layout.half_x or abs(cy - y0) > layout.half_y
        record = generate_clip("containment", "cube_random_position", seed)
        assert (record["mask"][VIDEO.num_frames // 2] == CUBE).sum() >= 10


def test_examples_are_not_constrained_to_hide_the_cube():
    heights, showing = [], 0
    for seed in range(8):
        rng = rng_for(seed, "test")
        layout, camera, _ = containment.clip_layout("example", rng, VIDEO)
        heights.append(layout.height / (2 * layout.cube_half))
    assert min(heights) < 1.0 < max(heights), "some containers are lower than the cube"
    for seed in range(10):  # about half of all examples show the cube (0.525 of 40 seeds)
        record = generate_clip("containment", "example", seed)
        showing += int((record["mask"][VIDEO.num_frames // 2] == CUBE).any())
        assert (record["camera"] == record["camera"][0]).all(), "static camera within a clip"
    assert showing >= 2, "in some examples the cube shows inside the container"


def test_bad_names_list_the_valid_ones():
    with pytest.raises(ValueError, match="standard"):
        containment.probe("three_pillars", 0, VIDEO)
    with pytest.raises(ValueError, match="cube_behind_container"):
        containment.clip("gap_block", 0, VIDEO)


def test_no_room_off_the_slide_is_a_rejection_not_a_hang():
    """A container whose slide sweeps the whole view leaves the randomly placed cube nowhere to
    land: the draw is rejected (and redrawn by draw_until_valid) instead of looping forever,
    which hung generation of 1,000+ containment controls."""
    rng = np.random.default_rng(0)
    layout, _ = containment.sample_layout(rng, VideoOptions(), containment.EXAMPLE_RANGES)
    layout.container_xy, layout.shift, layout.half_y = (-1.0, 0.0), 2.0, 1.0
    with pytest.raises(RejectedSample, match="no place for the cube off the container's slide"):
        containment.place_off_path(rng, layout)
    layout.shift, layout.half_y = 0.2, 0.1  # a small container: room to spare
    containment.place_off_path(rng, layout)
    assert -0.75 <= layout.cube_start[0] <= 0.75
