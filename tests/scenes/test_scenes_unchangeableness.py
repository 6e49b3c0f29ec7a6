"""Unchangeableness scenes (paper §3, §5): what each change's quadruplet changes behind the
screen, in both of its halves (that they splice exactly: tests/stats/test_quadruplets.py), the extra
objects of the generalization probes, and how examples and controls differ."""

import numpy as np
import pytest

from voe_lightning import specs
from voe_lightning.scenes import generate_clip, generate_probe
from voe_lightning.scenes import unchangeableness as scene
from voe_lightning.scenes.builder import SceneBuilder
from voe_lightning.scenes.camera import (
    CAMERA_PARAMETERS,
    CameraPose,
    VideoOptions,
    floor_point,
    height_above_view,
    image_point,
)
from voe_lightning.scenes.sampling import RejectedSample
from voe_lightning.scenes.screen import Screen
from voe_lightning.scenes.simulation import visible_ids

SEEDS = range(3)


def ids_at(mask, frame):
    return visible_ids(mask[frame].numpy())


def mean_color(record_video, frame, mask_id):
    pixels = record_video["frames"][frame].numpy()[record_video["mask"][frame].numpy() == mask_id]
    assert len(pixels), f"id {mask_id} is not visible at frame {frame}"
    return pixels.reshape(-1, 3).astype(float).mean(0)


def changed(record):
    return [i for i in record["manipulated_ids"].tolist() if i]


def row_ids(record):
    """Ids of the row's objects: all that show before the screen comes down (no screen yet)."""
    return ids_at(record["consistent"]["mask"], 0)


def halves(change):
    return pytest.mark.parametrize("variant", [change, f"{change}_counterbalanced"])


@halves("position")
@pytest.mark.parametrize("seed", SEEDS)
def test_position_probe_moves_objects_but_keeps_their_look(seed, variant):
    record = generate_probe("unchangeableness", variant, seed)
    m, ids = int(record["manipulation_frame"]), changed(record)
    consistent, inconsistent = record["consistent"], record["inconsistent"]
    assert 2 <= len(ids) <= 4 and set(ids) <= row_ids(record)
    # The screen hides the whole row at the manipulation, in both videos.
    assert not (ids_at(consistent["mask"], m) | ids_at(inconsistent["mask"], m)) & row_ids(record)
    last = -1
    assert ids_at(consistent["mask"], last) == ids_at(inconsistent["mask"], last) == row_ids(record)
    for mask_id in ids:

        def where(video, mask_id=mask_id):
            return np.argwhere(video["mask"][last].numpy() == mask_id).mean(0)

        assert abs(where(consistent)[1] - where(inconsistent)[1]) > 3, "object did not move"
        assert (
            np.abs(
                mean_color(consistent, last, mask_id) - mean_color(inconsistent, last, mask_id)
            ).max()
            < 40
        )


@halves("color")
@pytest.mark.parametrize("seed", SEEDS)
def test_color_probe_changes_colour_only(seed, variant):
    record = generate_probe("unchangeableness", variant, seed)
    consistent, inconsistent = record["consistent"], record["inconsistent"]
    # Same geometry throughout: the masks of the two videos are identical.
    assert (consistent["mask"] == inconsistent["mask"]).all()
    for mask_id in changed(record):
        before = mean_color(consistent, 0, mask_id)
        assert np.abs(mean_color(consistent, -1, mask_id) - before).max() < 20
        assert np.abs(mean_color(inconsistent, -1, mask_id) - before).max() > 40


@halves("shape")
@pytest.mark.parametrize("seed", SEEDS)
def test_shape_probe_swaps_in_a_same_coloured_twin_under_the_same_id(seed, variant):
    """The twin takes the id of the object it replaces (to a tracker, the same object
    changed), so both videos show the row's ids; its states name another shape, same colour.
    In the counterbalanced half the twin stands there from the start, under that id too."""
    record = generate_probe("unchangeableness", variant, seed)
    consistent, inconsistent = record["consistent"], record["inconsistent"]
    ids, m = changed(record), int(record["manipulation_frame"])
    assert 1 <= len(ids) <= scene.MOST_RESHAPED and set(ids) <= row_ids(record)
    assert ids_at(consistent["mask"], -1) == ids_at(inconsistent["mask"], -1) == row_ids(record)
    for mask_id in ids:
        colour = mean_color(consistent, 0, mask_id)
        assert np.abs(mean_color(inconsistent, -1, mask_id) - colour).max() < 40, "colour kept"
        # A different shape covers a different set of pixels where the original stood.
        where = [video["mask"][-1] == mask_id for video in (consistent, inconsistent)]
        assert (where[0] != where[1]).sum() >= 2
        shapes, colours = (
            [video["objects", key][:, mask_id] for video in (consistent, inconsistent)]
            for key in ("shape_label", "color")
        )
        assert (shapes[0] == shapes[0][0]).all() and (shapes[1][: m + 1] == shapes[0][0]).all()
        assert (shapes[1][m + 1 :] != shapes[0][0]).all() and (colours[0] == colours[1]).all()


@pytest.mark.parametrize("change", scene.CHANGES)
def test_the_two_halves_start_with_the_two_values_of_the_property(change):
    """A and B (the halves' consistent videos) show one row, the same camera and screen, and
    differ before the screen comes down only where the changed objects stand: in the property
    the change swaps, nowhere else."""
    for seed in SEEDS:
        a, b = (
            generate_probe("unchangeableness", v, seed)
            for v in (change, f"{change}_counterbalanced")
        )
        assert changed(a) == changed(b) and row_ids(a) == row_ids(b)
        frames, masks = (
            [video[key][0].numpy() for video in (a["consistent"], b["consistent"])]
            for key in ("frames", "mask")
        )
        differs = (frames[0] != frames[1]).any(-1)
        assert differs.any(), f"seed {seed}: A and B look alike before the change"
        where_changed = np.isin(masks[0], changed(a)) | np.isin(masks[1], changed(a))
        assert not (differs & ~where_changed).any(), f"seed {seed}: an unchanged object differs"


@pytest.mark.parametrize("change", scene.CHANGES)
def test_generalization_probes_have_one_or_two_more_objects_than_training(change):
    counts = {
        extra: {len(row_ids(generate_probe("unchangeableness", variant, s))) for s in SEEDS}
        for extra, variant in ((0, change), (1, f"{change}_plus1"), (2, f"{change}_plus2"))
    }
    assert counts[0] <= set(range(scene.MIN_OBJECTS, scene.MAX_OBJECTS + 1))
    assert counts[1] == {scene.MAX_OBJECTS + 1} and counts[2] == {scene.MAX_OBJECTS + 2}
    record = generate_probe("unchangeableness", f"{change}_plus2", 5)
    assert 1 <= len(changed(record)) <= 4


def test_training_clips_never_exceed_the_probe_object_count():
    for seed in range(4):
        clip = generate_clip("unchangeableness", "objects_only", seed)
        count = len(visible_ids(clip["mask"].numpy()))
        assert scene.MIN_OBJECTS <= count <= scene.MAX_OBJECTS


def screen_rows(mask, screen_id):
    """Lowest image row the screen covers in each frame (-1 where it is out of view)."""
    rows = []
    for frame in mask.numpy():
        hit = np.nonzero((frame == screen_id).any(1))[0]
        rows.append(int(hit.max()) if len(hit) else -1)
    return np.array(rows)


def test_controls_omit_the_screen_or_the_objects():
    objects_only = generate_clip("unchangeableness", "objects_only", 1)
    frames = objects_only["frames"]
    assert (frames == frames[0]).all(), "without a screen nothing moves"
    screen_only = generate_clip("unchangeableness", "screen_only", 1)
    ids = visible_ids(screen_only["mask"].numpy())
    assert len(ids) == 1, "only the screen"
    rows = screen_rows(screen_only["mask"], ids.pop())
    lowest = int(rows.argmax())
    assert rows[lowest] > rows[0] and rows[lowest] > rows[-1], "lowered, then raised"


def test_examples_scatter_objects_and_occlude_only_some():
    """Examples vary so much that the screen hides some objects, for a while, and not others."""
    hidden_some_time, always_visible = 0, 0
    for seed in range(6):
        clip = generate_clip("unchangeableness", "example", seed)
        mask = clip["mask"].numpy()
        ids = sorted(visible_ids(mask))
        screen_id, objects = ids[-1], ids[:-1]
        assert scene.MIN_OBJECTS <= len(objects) <= scene.MAX_OBJECTS
        rows = screen_rows(clip["mask"], screen_id)
        assert rows.max() > max(rows[0], rows[-1]), f"seed {seed}: the screen goes down and up"
        for mask_id in objects:
            shown = [mask_id in visible_ids(frame) for frame in mask]
            hidden_some_time += shown[0] and not all(shown)
            always_visible += all(shown)
    assert hidden_some_time and always_visible


def test_probes_align_objects_in_a_row():
    record = generate_probe("unchangeableness", "color", 2)
    mask = record["consistent"]["mask"][0].numpy()
    rows = [np.argwhere(mask == i)[:, 0].max() for i in sorted(row_ids(record))]
    assert max(rows) - min(rows) <= 4, "objects stand side by side at one depth"


def test_projection_matches_the_renderer():
    camera = CameraPose(lookat=(0.2, 0.3, 0.1), distance=3.0, azimuth=80, elevation=-30)
    for point in [(0.5, 1.0, 0.1), (-0.8, -0.3, 0.1)]:
        builder = SceneBuilder(np.random.default_rng(0), VideoOptions(), camera)
        builder.add_primitive("ball", "sphere", [0.08], point, "red", free=False)
        mask = builder.build().render()[1]
        ys, xs = np.nonzero(mask == 1)
        u, v = (xs.mean() + 0.5) / 32 - 1, 1 - (ys.mean() + 0.5) / 32
        assert np.allclose(image_point(camera, point), (u, v), atol=0.03)
        back = floor_point(camera, u, v, point[2])
        assert np.allclose(back[:2], point[:2], atol=0.08)


def test_other_video_geometry():
    record = generate_probe("unchangeableness", "shape", 0, num_frames=10, height=32, width=48)
    assert specs.probe_spec(10, 32, 48).is_in(record)
    m = int(record["manipulation_frame"])
    assert (record["consistent"]["frames"][:m] == record["inconsistent"]["frames"][:m]).all()


def test_bad_names_list_the_valid_ones():
    with pytest.raises(ValueError, match="valid variants"):
        scene.probe("size", 0, VideoOptions())
    with pytest.raises(ValueError, match="valid clip kind"):
        scene.clip("screen", 0, VideoOptions())


def _screen_parameters(screen: Screen, camera: CameraPose) -> dict[str, float]:
    motion = screen.motion
    return {
        "screen_dx": screen.x - camera.lookat[0],
        "screen_dy": screen.y - camera.lookat[1],
        "screen_width": screen.width,
        "screen_height": screen.height,
        "screen_bottom": motion.bottom,
        "screen_start_above_view": motion.top - height_above_view(camera, screen.x, screen.y),
        "screen_start": motion.start,
        "screen_lowering": motion.down - motion.start,
        "screen_held_down": motion.up - motion.down,
        "screen_raising": motion.end - motion.up,
        **dict(zip(CAMERA_PARAMETERS, camera.as_array().tolist())),
    }


def _object_parameters(draw: scene.ObjectDraw, x: float, y: float, camera) -> dict[str, float]:
    return {
        "object_radius": draw.radius,
        "object_height": draw.height,
        "object_dx": x - camera.lookat[0],
        "object_dy": y - camera.lookat[1],
    }


def _stack(draws: list[dict]) -> dict[str, np.ndarray]:
    return {name: np.array([d[name] for d in draws]) for name in draws[0]}


def _example_draws(count: int) -> tuple[dict, dict]:
    rng, video, screens, objects = np.random.default_rng(1), VideoOptions(), [], []
    while len(screens) < count:
        camera = scene.CAMERA.sample(rng)
        screen = scene.draw_example_screen(rng, camera, video)
        try:
            placed = scene.scatter_objects(rng, camera, screen, 1.0)
        except RejectedSample:
            continue
        screens.append(_screen_parameters(screen, camera))
        objects += [_object_parameters(draw, x, y, camera) for draw, x, y in placed]
    return _stack(screens), _stack(objects)


def _probe_draws(count: int, counts) -> tuple[dict, dict]:
    rng, video, screens, objects = np.random.default_rng(2), VideoOptions(), [], []
    while len(screens) < count:
        try:
            layout = scene.probe_layout(rng, int(rng.choice(counts)), video)
        except RejectedSample:
            continue
        screens.append(_screen_parameters(layout.screen, layout.camera))
        objects += [
            _object_parameters(draw, x, layout.row_y, layout.camera)
            for draw, x in zip(layout.draws, layout.xs)
        ]
    return _stack(screens), _stack(objects)


@pytest.mark.parametrize(
    "counts", [(2, 3, 4), (scene.MAX_OBJECTS + 1, scene.MAX_OBJECTS + 2)], ids=["standard", "plus"]
)
def test_probe_parameters_lie_inside_the_examples_with_real_mass(counts):
    """Examples are like probes but not constrained: every probe screen (size, depth, timing),
    object (size, place relative to the camera) and camera parameter lies inside the examples'
    range, and 5% of the examples fall inside the probes' range."""
    example_screens, example_objects = _example_draws(1500)
    probe_screens, probe_objects = _probe_draws(1000, counts)
    for examples, probes in ((example_screens, probe_screens), (example_objects, probe_objects)):
        for name, values in probes.items():
            low, high = examples[name].min(), examples[name].max()
            slack = 0.01 * (high - low) + 1e-9  # both may sample one bound: sampling noise
            assert low - slack <= values.min() and values.max() <= high + slack, (
                f"probe {name} [{values.min():.3f}, {values.max():.3f}] leaves the examples' "
                f"[{low:.3f}, {high:.3f}]"
            )
            if high > low:
                inside = (examples[name] >= values.min()) & (examples[name] <= values.max())
                assert inside.mean() >= 0.05, (
                    f"only {inside.mean():.2f} of examples near probe {name}"
                )


def test_example_screens_are_often_placed_and_sized_like_the_probes():
    """Jointly, 5% of the example screens are placed and sized like the standard probes' (the
    probes' screen is no extreme of training)."""
    example_screens, _ = _example_draws(1500)
    probe_screens, _ = _probe_draws(1000, (2, 3, 4))
    like_probes = np.ones(len(example_screens["screen_dx"]), bool)
    for name in ("screen_dx", "screen_dy", "screen_width", "screen_height"):
        values = probe_screens[name]
        like_probes &= (example_screens[name] >= values.min()) & (
            example_screens[name] <= values.max()
        )
    assert like_probes.mean() >= 0.05, (
        f"only {like_probes.mean():.2f} of example screens like probes'"
    )
