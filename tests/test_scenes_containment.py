"""Containment scenes: the cube really rides in the sliding container (and stays put after the
hidden release), the rod comes down from above, and the controls and examples differ from the
probes the way the paper says."""

import numpy as np
import pytest
import torch

from voe_lightning.scenes import base, containment, generate_clip, generate_probe

VIDEO = base.VideoOptions()
CONTAINER, CUBE, ROD = 1, 2, 3  # mask ids in the order the scene adds them


def centroid_column(mask: torch.Tensor, object_id: int) -> float:
    return float(torch.nonzero(mask == object_id)[:, 1].float().mean())


@pytest.fixture(scope="module")
def probe_record():
    return generate_probe("containment", "standard", 3)


def test_container_is_one_object_of_five_boxes():
    rng = np.random.default_rng(0)
    layout, _ = containment.probe_layout(rng, VIDEO)
    sim = containment.build(rng, VIDEO, containment.PROBE_CAMERA, layout)
    geoms = sim.objects["container"].geom_names
    assert len(geoms) == 5
    assert {int(sim.geom_mask_id[sim.model.geom(g).id]) for g in geoms} == {CONTAINER}


def test_cube_rides_along_and_stays_behind_when_released():
    rng = np.random.default_rng(4)
    layout, frame = containment.probe_layout(rng, VIDEO)
    sim = containment.build(rng, VIDEO, containment.PROBE_CAMERA, layout)
    sim.step(frame * VIDEO.steps_per_frame)
    resting = sim.position("cube")
    on_bottom = containment.WALL + layout.cube_half
    assert resting[2] == pytest.approx(on_bottom, abs=0.01), "the cube rests on the bottom"
    twin = sim.fork()
    containment.release_cube(twin)
    rest = (VIDEO.num_frames - frame) * VIDEO.steps_per_frame
    sim.step(rest)
    twin.step(rest)
    container_moved = sim.position("container")[0] - layout.container_xy[0]
    assert container_moved == pytest.approx(layout.shift, abs=0.02)
    carried = sim.position("cube") - resting
    assert carried[0] == pytest.approx(layout.shift, abs=layout.half_x), "the cube moves with it"
    left = twin.position("cube") - resting
    assert np.abs(left[:2]).max() < 0.01, "released, the cube stays where it was"
    assert left[2] == pytest.approx(-containment.WALL, abs=0.01), "dropped by the bottom's width"


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
        rng = base.rng_for(seed, "test")
        layout, _, _ = containment.clip_layout("cube_random_position", rng, VIDEO)
        x0, y0 = layout.container_xy
        cx, cy, _ = layout.cube_start
        assert abs(cx - x0) > layout.half_x or abs(cy - y0) > layout.half_y
        record = generate_clip("containment", "cube_random_position", seed)
        assert (record["mask"][VIDEO.num_frames // 2] == CUBE).sum() >= 10


def test_examples_are_not_constrained_to_hide_the_cube():
    heights, showing = [], 0
    for seed in range(8):
        rng = base.rng_for(seed, "test")
        layout, camera, _ = containment.clip_layout("example", rng, VIDEO)
        heights.append(layout.height / (2 * layout.cube_half))
    assert min(heights) < 1.0 < max(heights), "some containers are lower than the cube"
    for seed in range(4):
        record = generate_clip("containment", "example", seed)
        showing += int((record["mask"][VIDEO.num_frames // 2] == CUBE).any())
        assert (record["camera"] == record["camera"][0]).all(), "static camera within a clip"
    assert showing >= 1, "in some examples the cube shows inside the container"


def test_bad_names_list_the_valid_ones():
    with pytest.raises(ValueError, match="standard"):
        containment.probe("three_pillars", 0, VIDEO)
    with pytest.raises(ValueError, match="cube_behind_container"):
        containment.clip("gap_block", 0, VIDEO)
