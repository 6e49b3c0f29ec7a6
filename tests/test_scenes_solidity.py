"""Solidity scenes, beyond the shared validity test: perspective control (the probe camera sees
inside the top of the container, never its bottom), the block rests visibly in the consistent
probe and vanishes in the inconsistent one, and the controls are what the paper says."""

import numpy as np
import pytest
import torch

from voe_lightning.scenes import VideoOptions, generate_clip, generate_probe, solidity
from voe_lightning.scenes.base import Geom, SceneBuilder, visible_ids

CONCEPT = "solidity"
CONTAINER, BLOCK = 1, 2  # mask ids: the container is added first


def ids_in(mask: torch.Tensor) -> set[int]:
    return set(mask.unique().tolist()) - {0}


@pytest.mark.parametrize("seed", range(6))
def test_probe_camera_sees_into_the_top_but_not_the_bottom(seed):
    rng = np.random.default_rng(seed)
    box = solidity._draw_container(rng)
    camera = solidity._probe_camera(rng, box)
    builder = SceneBuilder(rng, VideoOptions(height=128, width=128), camera)
    solidity._add_container(builder, box, "red")
    ix, iy, w, h = box["inner_x"], box["inner_y"], box["wall"], box["height"]
    # Thin markers: one covering the inner bottom, one on the back wall's inner face near the rim.
    bottom = builder.add(
        "bottom", [Geom("box", (ix, iy, 0.004))], (0, 0, 2 * w + 0.004), "blue", free=False
    )
    back = builder.add(
        "back", [Geom("box", (ix, 0.004, 0.04))], (0, iy - 0.004, h - 0.05), "green", free=False
    )
    _, mask = builder.build().render()
    assert back.mask_id in visible_ids(mask), "the camera must see inside the top"
    assert bottom.mask_id not in visible_ids(mask), "the camera must not see the bottom"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_probe_block_rests_visibly_or_falls_out_of_view(seed):
    record = generate_probe(CONCEPT, "standard", seed)
    assert record["manipulated_ids"].tolist() == [BLOCK, 0, 0, 0]
    m = int(record["manipulation_frame"])
    consistent, inconsistent = record["consistent", "mask"], record["inconsistent", "mask"]
    assert BLOCK in ids_in(consistent[0]), "the block is seen before it drops"
    # Tall enough to protrude: the resting block stays in view to the end ...
    assert all(BLOCK in ids_in(frame) for frame in consistent[m:])
    # ... while the one falling through sinks (never showing more) and is gone at the end.
    shown = (inconsistent[m:] == BLOCK).flatten(1).sum(1)
    assert (shown[1:] <= shown[:-1]).all() and shown[-1] == 0
    # The container itself never changes: what the resting block does not cover shows alike.
    lost = (consistent == CONTAINER) & (inconsistent != CONTAINER)
    assert lost.flatten(1).sum(1).max() <= solidity.PENETRATION_TOLERANCE


def test_no_object_control_shows_only_the_container():
    for seed in range(3):
        record = generate_clip(CONCEPT, "no_object", seed)
        assert all(ids_in(frame) == {CONTAINER} for frame in record["mask"])


def test_object_behind_container_is_occluded_by_it_from_behind():
    for seed in range(3):
        mask = generate_clip(CONCEPT, "object_behind_container", seed)["mask"]
        assert BLOCK in ids_in(mask[0])
        final_block, container = mask[-1] == BLOCK, mask[-1] == CONTAINER
        # Resting behind the container on the floor: its lowest visible pixel is higher in
        # the picture than the container's lowest (front) edge.
        if final_block.any():
            lowest = lambda m: int(torch.nonzero(m.any(dim=1)).max())  # noqa: E731
            assert lowest(final_block) < lowest(container)


def test_examples_include_hidden_and_protruding_blocks_and_vary_the_camera():
    records = [generate_clip(CONCEPT, "example", seed) for seed in range(8)]
    final_visible = [BLOCK in ids_in(record["mask"][-1]) for record in records]
    assert all(BLOCK in ids_in(record["mask"][0]) for record in records)
    elevations = torch.stack([record["camera"][0, 5] for record in records])
    assert elevations.max() - elevations.min() > 10, "perspective is not controlled in examples"
    assert any(final_visible), "some blocks protrude above the rim"


def test_block_fits_inside_the_container():
    for seed in range(30):
        rng = np.random.default_rng(seed)
        box = solidity._draw_container(rng)
        block = solidity._draw_block(rng, box, heights=(0.3, 1.7))
        half_x, half_y, _ = block["half"]
        cos, sin = abs(np.cos(block["yaw"])), abs(np.sin(block["yaw"]))
        assert abs(block["offset"][0]) + half_x * cos + half_y * sin < box["inner_x"]
        assert abs(block["offset"][1]) + half_x * sin + half_y * cos < box["inner_y"]


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda: solidity.clip("example_behind", 0, VideoOptions()), "valid: example"),
        (lambda: solidity.probe("counterbalanced", 0, VideoOptions()), "valid: standard"),
    ],
)
def test_bad_names_list_valid_ones(call, match):
    with pytest.raises(ValueError, match=match):
        call()
