"""Continuity scenes: the ball's hidden disappearance and on-course return, the extra pillar of
the generalization probe, the gap_block control's visibility pattern, unconstrained examples."""

import numpy as np
import pytest
import torch

from voe_lightning.scenes import base, continuity, generate_clip, generate_probe

VIDEO = base.VideoOptions()
PILLAR_HALF_DEPTH = continuity.PILLAR_DEPTH / 2


@pytest.fixture(scope="module", params=["standard", "three_pillars"])
def probe_record(request):
    return request.param, generate_probe("continuity", request.param, 5)


def ball_visible(mask: torch.Tensor, ball: int) -> np.ndarray:
    return (mask == ball).flatten(1).any(1).numpy()


def test_ball_vanishes_behind_first_pillar_and_returns_on_course(probe_record):
    variant, record = probe_record
    m = int(record["manipulation_frame"])
    ball = int(record["manipulated_ids"][0])
    consistent, inconsistent = record["consistent"], record["inconsistent"]
    seen_consistent = ball_visible(consistent["mask"], ball)
    seen_inconsistent = ball_visible(inconsistent["mask"], ball)
    assert seen_consistent[:m].any(), "the ball must be seen before it goes behind the first pillar"
    back = m + int(np.argmax(seen_inconsistent[m:]))
    assert seen_inconsistent[back], "the ball must reappear after the last pillar"
    assert not seen_inconsistent[m:back].any()
    assert seen_consistent[m:back].any(), "in the consistent probe the ball crosses the gap"
    # Restored at the physically right position and velocity: identical from then on.
    assert torch.equal(consistent["frames"][back:], inconsistent["frames"][back:])
    assert torch.equal(consistent["mask"][back:], inconsistent["mask"][back:])
    # While it is gone, the videos differ only where the consistent ball is.
    differs = (consistent["frames"][m:back] != inconsistent["frames"][m:back]).any(-1)
    assert not (differs & (consistent["mask"][m:back] != ball)).any()


def test_three_pillars_has_an_extra_pillar(probe_record):
    variant, record = probe_record
    pillars = 3 if variant == "three_pillars" else 2
    ball = int(record["manipulated_ids"][0])
    assert ball == pillars + 1, "pillars get ids 1..n, the ball the next one"
    first = record["consistent", "mask"][0]
    assert set(range(1, pillars + 1)) <= set(first.unique().tolist())


def test_examples_never_have_three_pillars_and_paths_are_unconstrained():
    depths = []
    for seed in range(6):
        rng = base.rng_for(seed, "test")
        layout = continuity.example_layout(rng, VIDEO.duration)
        assert len(layout.pillars) == 2
        depths.append(layout.ball_start[1])
    assert min(depths) < -PILLAR_HALF_DEPTH and max(depths) > PILLAR_HALF_DEPTH, (
        "examples roll the ball in front of as well as behind the pillars"
    )
    for seed in range(3):
        record = generate_clip("continuity", "example", seed)
        assert set(record["mask"].unique().tolist()) <= {0, 1, 2, 3}, "two pillars and a ball"
        assert ball_visible(record["mask"], 3).sum() >= VIDEO.num_frames / 3
        assert (record["camera"] == record["camera"][0]).all(), "static camera within a clip"


def test_gap_block_shows_the_ball_only_before_and_after_the_pillars():
    record = generate_clip("continuity", "gap_block", 2)
    block, ball = 3, 4
    assert (record["mask"] == block).any(), "the block between the pillars is visible"
    visible_frames = np.flatnonzero(ball_visible(record["mask"], ball))
    # Seen before the pillars, hidden for the whole crossing, seen again after them.
    assert np.diff(visible_frames).max() >= 3, f"the ball shows at frames {visible_frames}"


def test_ball_keeps_rolling_across_the_view():
    rng = np.random.default_rng(0)
    layout = continuity.probe_layout(rng, 2, VIDEO.duration)
    sim = continuity.build(rng, VIDEO, continuity.PROBE_CAMERA, layout)
    start = sim.position("ball")
    sim.step(VIDEO.steps_per_frame * VIDEO.num_frames)
    travelled = sim.position("ball") - start
    expected = layout.ball_velocity[0] * VIDEO.steps_per_frame * VIDEO.num_frames * VIDEO.timestep
    assert travelled[0] == pytest.approx(expected, rel=0.05), "rolling without slipping or stopping"
    assert abs(travelled[1]) < 0.01 and abs(travelled[2]) < 0.01


def test_projection_lands_on_the_rendered_ball():
    rng = np.random.default_rng(1)
    layout = continuity.probe_layout(rng, 2, VIDEO.duration)
    sim = continuity.build(rng, VIDEO, continuity.PROBE_CAMERA, layout)
    frames, masks, states, positions = continuity.record_tracking_ball(sim)
    seen = continuity.what_hides_ball(sim, masks, positions)
    ball = sim.mask_id("ball")
    visible_in_frame = (continuity.ball_pixels(masks, ball) > 10) & (seen != -1)
    assert visible_in_frame.sum() >= 5
    assert (seen[visible_in_frame] == ball).all(), "the projected centre lies on the ball"
    assert len(states) == VIDEO.num_frames


def test_bad_variant_names_the_valid_ones():
    with pytest.raises(ValueError, match="three_pillars"):
        continuity.probe("four_pillars", 0, VIDEO)
    with pytest.raises(ValueError, match="gap_block"):
        continuity.clip("cube_random_position", 0, VIDEO)
