"""Object persistence scenes, beyond the shared validity test: the plank ends propped up on
the object or flat on the floor, the counterbalanced probe starts empty, and the controls show
what the paper says (a visible object the plank does not touch; an empty floor)."""

import mujoco
import numpy as np
import pytest
import torch

from voe_lightning.scenes import VideoOptions, generate_clip, generate_probe, object_persistence
from voe_lightning.scenes.camera import CAMERA_PARAMETERS
from voe_lightning.scenes.sampling import RejectedSample

CONCEPT = "object_persistence"


def top_row(mask: torch.Tensor, object_id: int) -> int:
    """The highest image row showing ``object_id`` (a propped plank reaches higher)."""
    rows = torch.nonzero((mask == object_id).any(dim=1))
    assert len(rows), f"object {object_id} not visible"
    return int(rows.min())


def ids_in(mask: torch.Tensor) -> set[int]:
    return set(mask.unique().tolist()) - {0}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_standard_probe_object_vanishes_from_under_the_plank(seed):
    record = generate_probe(CONCEPT, "standard", seed)
    obj = int(record["manipulated_ids"][0])
    m = int(record["manipulation_frame"])
    consistent, inconsistent = record["consistent", "mask"], record["inconsistent", "mask"]
    (plank,) = ids_in(consistent[0]) - {obj}
    assert obj in ids_in(consistent[0]), "the object is seen before the plank falls on it"
    # Consistent: the plank hides the object it rests on; inconsistent: the object is gone.
    assert not (consistent[m:] == obj).any() and not (inconsistent[m:] == obj).any()
    # The propped plank rises higher in the picture than the plank lying flat.
    assert top_row(consistent[-1], plank) < top_row(inconsistent[-1], plank) - 1


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_counterbalanced_probe_starts_empty_and_ends_propped(seed):
    record = generate_probe(CONCEPT, "counterbalanced", seed)
    obj = int(record["manipulated_ids"][0])
    consistent, inconsistent = record["consistent", "mask"], record["inconsistent", "mask"]
    # An empty scene: only the plank is ever seen, in both videos.
    assert ids_in(consistent) == ids_in(inconsistent) == ids_in(consistent[0])
    assert obj not in ids_in(consistent) and len(ids_in(consistent)) == 1
    (plank,) = ids_in(consistent)
    # Yet the inconsistent plank ends propped up by the object that appeared under it.
    assert top_row(inconsistent[-1], plank) < top_row(consistent[-1], plank) - 1


def test_plank_on_empty_floor_shows_only_the_plank():
    for seed in range(3):
        mask = generate_clip(CONCEPT, "plank_on_empty_floor", seed)["mask"]
        assert all(len(ids_in(frame)) == 1 for frame in mask)
        assert ids_in(mask[0]) == ids_in(mask[-1])


def test_plank_beside_object_leaves_the_object_visible_and_untouched():
    for seed in range(3):
        mask = generate_clip(CONCEPT, "plank_beside_object", seed)["mask"]
        obj, plank = 1, 2  # the object is added first
        first, last = mask[0] == obj, mask[-1] == obj
        assert first.sum() > 0 and plank in ids_in(mask[-1])
        # Not supporting the plank, so not pushed: the object's pixels stay where they were.
        assert last.sum() >= 0.7 * first.sum()
        centroid = lambda m: torch.nonzero(m).float().mean(0)  # noqa: E731
        assert torch.dist(centroid(first), centroid(last)) < 1.5


def test_examples_vary_objects_and_cameras():
    records = [generate_clip(CONCEPT, "example", seed) for seed in range(4)]
    for record in records:
        assert ids_in(record["mask"][0]) == {1, 2}, "object and plank both in view at the start"
        assert (record["camera"] == record["camera"][0]).all(), "camera static within a clip"
    cameras = torch.stack([record["camera"][0] for record in records])
    assert len(cameras.unique(dim=0)) == 4, "camera varies between clips"
    object_areas = {int((record["mask"][0] == 1).sum()) for record in records}
    assert len(object_areas) == 4


def test_probe_layout_props_the_plank_behind_its_middle():
    """By construction the object meets the plank behind the plank's centre of mass (so the
    plank stays propped) and the plank is wide enough to hide the object."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        layout = object_persistence.probe_layout(rng)
        half_width, half_length, _ = layout["plank_half"]
        center_y = layout["plank_center"][1]
        obj_y = layout["object_xy"][1]
        assert center_y < obj_y < center_y + 2 * half_length
        assert half_width > layout["object"]["half"] + 0.25
        assert object_persistence.PROBE_CAMERA.contains(layout["camera"])


def _tilt_degrees(quat) -> float:
    """Angle between the plank's face normal and the vertical."""
    rotation = np.empty(9)
    mujoco.mju_quat2Mat(rotation, np.asarray(quat, float))
    return float(np.degrees(np.arccos(abs(rotation[8]))))


def _parameters(layout: dict) -> dict[str, float]:
    half = layout["plank_half"]
    return {
        "object_half": layout["object"]["half"],
        "plank_short_half": min(half[0], half[1]),
        "plank_long_half": max(half[0], half[1]),
        "plank_half_thickness": half[2],
        "plank_tilt": _tilt_degrees(layout["plank_quat"]),
        "drop_height": layout["drop"],
        **dict(zip(CAMERA_PARAMETERS, layout["camera"].as_array().tolist())),
        # Where the object stands relative to where the camera looks.
        "object_dx": layout["object_xy"][0] - layout["camera"].lookat[0],
        "object_dy": layout["object_xy"][1] - layout["camera"].lookat[1],
    }


def _draw(sampler, count: int) -> dict[str, np.ndarray]:
    rng, draws = np.random.default_rng(1), []
    while len(draws) < count:
        try:
            draws.append(_parameters(sampler(rng)))
        except RejectedSample:
            continue
    return {name: np.array([d[name] for d in draws]) for name in draws[0]}


def test_probe_parameters_lie_inside_the_examples_with_real_mass():
    """Examples are like probes but not constrained: every probe parameter (object, plank,
    drop, camera, object placement) lies inside the examples' range, and at least a tenth of
    the examples fall inside the probes' range."""
    examples = _draw(lambda rng: object_persistence.clip_layout(rng, "example"), 1500)
    probes = _draw(object_persistence.probe_layout, 1500)
    for name, values in probes.items():
        low, high = examples[name].min(), examples[name].max()
        slack = 0.01 * (high - low)  # both sample the same bound: allow sampling noise there
        assert low - slack <= values.min() and values.max() <= high + slack, (
            f"probe {name} [{values.min():.3f}, {values.max():.3f}] leaves the examples' "
            f"[{low:.3f}, {high:.3f}]"
        )
        inside = (examples[name] >= values.min()) & (examples[name] <= values.max())
        assert inside.mean() >= 0.1, f"only {inside.mean():.2f} of examples near probe {name}"


@pytest.mark.parametrize("variant", ["standard", "counterbalanced"])
def test_change_happens_on_a_frame_while_hidden(variant):
    """The change is made at a frame (not between frames), so the pair is byte-identical through
    the manipulation frame, and before the plank settles (several frames remain to show it)."""
    for seed in range(4):
        record = generate_probe(CONCEPT, variant, seed)
        m = int(record["manipulation_frame"])
        for key in ("frames", "mask"):
            assert torch.equal(
                record["consistent", key][: m + 1], record["inconsistent", key][: m + 1]
            )
        assert 1 <= m <= record["consistent", "mask"].shape[0] - 3


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda: object_persistence.clip("gap_block", 0, VideoOptions()), "are: example"),
        (lambda: object_persistence.probe("color", 0, VideoOptions()), "standard, counterbalanced"),
    ],
)
def test_bad_names_list_valid_ones(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_every_clip_kind_drops_the_plank_from_the_same_heights():
    """A plank's starting height must not tell whether it will land on an object: controls drop
    it from over a (virtual) object's top, as examples do (the positive control, trained when
    controls dropped it from lower, expected every high plank to end propped). Same seeds:
    identical heights; across seeds: one distribution (two-sample KS test)."""
    from scipy.stats import ks_2samp

    kinds = ("example", "plank_beside_object", "plank_on_empty_floor")
    heights = {
        kind: np.array(
            [
                object_persistence.clip_layout(np.random.default_rng(seed), kind)["plank_center"][2]
                for seed in range(300)
            ]
        )
        for kind in kinds
    }
    for kind in kinds[1:]:
        np.testing.assert_allclose(heights[kind], heights["example"])
    shifted = np.array(
        [
            object_persistence.clip_layout(
                np.random.default_rng(1000 + seed), "plank_on_empty_floor"
            )["plank_center"][2]
            for seed in range(300)
        ]
    )
    assert ks_2samp(heights["example"], shifted).pvalue > 0.01
