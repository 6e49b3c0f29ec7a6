"""Validity (docs/architecture.md §4), for every concept and probe variant over several seeds:
frames identical through the manipulation frame, hidden manipulation, a real difference afterwards,
determinism, records matching the specs, one camera distribution per concept, and no
physics-blind cue in any concept's balanced pool of probes. Set VOE_VALIDITY_SEEDS to check
more seeds (CI uses a few; run with 50 before changing a scene) and VOE_FAIRNESS_PAIRS for
more pairs in the cue test."""

import os

import numpy as np
import pytest
import torch
from helpers import ALPHA
from helpers.probes import check_probe_pair
from scipy import stats

from voe_lightning import specs
from voe_lightning.audit import cues, video_cues
from voe_lightning.scenes import (
    CLIP_KINDS_BY_CONCEPT,
    CONCEPTS,
    PROBE_VARIANTS,
    concept_scene,
    generate_clip,
    generate_probe,
)

NUM_SEEDS = int(os.environ.get("VOE_VALIDITY_SEEDS", "3"))
FAIRNESS_PAIRS = int(os.environ.get("VOE_FAIRNESS_PAIRS", "150"))
CAMERA_CLIPS = int(os.environ.get("VOE_CAMERA_CLIPS", "30"))
PROBE_CASES = [(c, v) for c in CONCEPTS for v in PROBE_VARIANTS[c]]
CLIP_CASES = [(c, k) for c in CONCEPTS for k in CLIP_KINDS_BY_CONCEPT[c]]


@pytest.mark.parametrize("concept,variant", PROBE_CASES)
def test_probe_pairs_are_valid(concept, variant):
    spec = specs.probe_spec()
    for seed in range(NUM_SEEDS):
        record = generate_probe(concept, variant, seed)
        assert spec.is_in(record), f"{concept}/{variant} seed {seed} does not match the spec"
        assert specs.concept_name(record) == concept and specs.variant_name(record) == variant
        where = f"{concept}/{variant} seed {seed}"
        check_probe_pair(record, concept, variant, where)
        for video in ("consistent", "inconsistent"):
            check_objects_agree_with_mask(record[video], f"{where} {video}")


def check_objects_agree_with_mask(video, where: str) -> None:
    """A video's object states hold a slot for every id its mask shows, visible_fraction is
    that id's share of the pixels (0 exactly where the mask lacks it), slots without an
    object are all zeros, and present objects have unit quaternions, positive sizes and
    colours in [0, 1]."""
    mask, objects = video["mask"].long(), video["objects"]
    share = (mask[..., None] == torch.arange(specs.OBJECT_SLOTS)).float().mean(dim=(1, 2))
    share[:, 0] = 0.0  # the background is no object
    assert torch.equal(objects["visible_fraction"], share), f"{where}: visible_fraction != mask"
    present = objects["shape_label"] > 0
    shown = share > 0
    assert not (shown & ~present).any(), (
        f"{where}: ids {mask.unique().tolist()} shown without states"
    )
    assert not present[:, 0].any(), f"{where}: the background holds an object"
    for name in ("position", "orientation", "size", "color"):
        assert not objects[name][~present].any(), f"{where}: absent objects have a {name}"
    norms = objects["orientation"][present].norm(dim=-1)
    torch.testing.assert_close(norms, torch.ones_like(norms))
    assert (objects["size"][present] > 0).all(), f"{where}: an object without size"
    colors = objects["color"][present]
    assert ((colors >= 0) & (colors <= 1)).all(), f"{where}: colour outside [0, 1]"


@pytest.mark.parametrize("concept,kind", CLIP_CASES)
def test_clip_object_states_agree_with_masks(concept, kind):
    for seed in range(NUM_SEEDS):
        check_objects_agree_with_mask(
            generate_clip(concept, kind, seed), f"{concept} {kind} seed {seed}"
        )


def _present(record, video: str, object_id: int) -> list[bool]:
    return (record[video, "objects", "shape_label"][:, object_id] > 0).tolist()


@pytest.mark.parametrize("seed", range(NUM_SEEDS))
def test_object_states_follow_the_hidden_changes(seed):
    """States are the scene's ground truth: an object taken out of the scene is absent while
    it is out (and one that appears, until it does), a container is one compound object
    whose box stands on the floor, a ball rolls at its radius above it, and a changed colour,
    place or path (solidity's quadruplet: the short block stopping where the tall one rests)
    shows in the states from the frame after the manipulation (solidity's counterbalanced block
    keeps its size, its top where the tall block's rests)."""
    record = generate_probe("continuity", "paper", seed)
    m, ball = int(record["manipulation_frame"]), int(record["manipulated_ids"][0])
    assert all(_present(record, "consistent", ball))
    gone = _present(record, "inconsistent", ball)
    assert all(gone[: m + 1]) and not all(gone[m + 1 :]) and gone[-1]
    states = record["consistent", "objects"]
    radius = states["size"][:, ball]
    torch.testing.assert_close(radius, radius[:, :1].expand(-1, 3))
    torch.testing.assert_close(states["position"][:, ball, 2], radius[:, 2], atol=2e-3, rtol=0)
    assert (states["shape_label"][:, ball] == specs.OBJECT_SHAPES.index("sphere")).all()

    for variant, appears in (("standard", False), ("counterbalanced", True)):
        record = generate_probe("object_persistence", variant, seed)
        m, obj = int(record["manipulation_frame"]), int(record["manipulated_ids"][0])
        steady, changed = _present(record, "consistent", obj), _present(record, "inconsistent", obj)
        assert steady == [not appears] * len(steady)
        assert changed == [not appears] * (m + 1) + [appears] * (len(changed) - m - 1)

    record = generate_probe("solidity", "counterbalanced", seed)
    m, block = int(record["manipulation_frame"]), int(record["manipulated_ids"][0])
    size = [
        record[video, "objects", "size"][:, block, 2] for video in ("consistent", "inconsistent")
    ]
    assert (size[0] == size[0][0]).all() and (size[1] == size[0][0]).all(), "a block keeps its size"
    tall = generate_probe("solidity", "standard", seed)["consistent", "objects"]
    top = tall["position"][:, block, 2] + tall["size"][:, block, 2]
    stopped = record["inconsistent", "objects"]["position"][:, block, 2] + size[1]
    torch.testing.assert_close(stopped[m + 1 :], top[m + 1 :])  # short, stopped where tall rests
    states = record["consistent", "objects"]
    container = int((states["shape_label"][0] == specs.OBJECT_SHAPES.index("compound")).nonzero())
    torch.testing.assert_close(states["position"][:, container, 2], states["size"][:, container, 2])

    for change, key in (("color", "color"), ("position", "position")):
        record = generate_probe("unchangeableness", change, seed)
        m = int(record["manipulation_frame"])
        for object_id in [i for i in record["manipulated_ids"].tolist() if i]:
            before, after = (
                record[video, "objects", key][:, object_id]
                for video in ("consistent", "inconsistent")
            )
            assert torch.equal(before[: m + 1], after[: m + 1])
            assert not torch.isclose(before[m + 1 :], after[m + 1 :]).all(dim=-1).any()


#: Probe variants whose inconsistent video holds an object the consistent one never has: it
#: appears by design, hidden, so its id is in the inconsistent video's object states only (in
#: neither mask). No variant's object vanishes from a whole video: each is seen, or held in
#: the states, before the change.
APPEARS_BY_DESIGN = {
    ("object_persistence", "counterbalanced"): "the object appears under the falling plank",
}


def _ids(record, video: str) -> tuple[set[int], set[int]]:
    """The ids a video's masks show and the ids its object states hold, over the video."""
    shown = set(record[video, "mask"].unique().tolist()) - {0}
    held = (record[video, "objects", "shape_label"] > 0).any(dim=0).nonzero().flatten()
    return shown, set(held.tolist())


@pytest.mark.parametrize("concept,variant", PROBE_CASES)
def test_a_pair_holds_the_same_ids_unless_an_object_appears_by_design(concept, variant):
    """Mask ids are what a tracker would give (docs/architecture.md §4): a body swapped in or moved
    while hidden keeps the id of the one it replaced, so both videos of a pair show the same ids,
    and their states hold the same ids except for an object that appears by design."""
    for seed in range(NUM_SEEDS):
        record = generate_probe(concept, variant, seed)
        (shown, held), (shown_changed, held_changed) = (
            _ids(record, video) for video in ("consistent", "inconsistent")
        )
        where = f"{concept}/{variant} seed {seed}"
        assert shown == shown_changed, f"{where}: masks show ids {shown} and {shown_changed}"
        if (concept, variant) in APPEARS_BY_DESIGN:
            manipulated = set(record["manipulated_ids"].tolist()) - {0}
            assert held_changed - held == manipulated and held <= held_changed, where
        else:
            assert held == held_changed, f"{where}: states hold ids {held} and {held_changed}"


@pytest.mark.parametrize("concept,variant", PROBE_CASES)
def test_probe_is_deterministic(concept, variant):
    first, second = generate_probe(concept, variant, 7), generate_probe(concept, variant, 7)
    assert (first == second).all()


@pytest.mark.parametrize("concept,kind", CLIP_CASES)
def test_clips_match_spec_and_are_deterministic(concept, kind):
    spec = specs.clip_spec()
    first = generate_clip(concept, kind, 3)
    assert spec.is_in(first)
    assert (first == generate_clip(concept, kind, 3)).all()
    assert not (first == generate_clip(concept, kind, 4)).all(), "seeds must give different clips"
    # Something moves or is visible: no blank clips.
    assert first["frames"].float().std() > 1.0


def test_video_options_change_the_geometry():
    record = generate_clip("continuity", "example", 0, num_frames=8, height=32, width=48)
    assert record["frames"].shape == (8, 32, 48, 3)
    assert specs.clip_spec(8, 32, 48).is_in(record)


@pytest.mark.parametrize(
    "call,match",
    [
        (lambda: generate_clip("gravity", "example", 0), "valid concepts are"),
        (lambda: generate_clip("continuity", "bogus", 0), "valid clip kind"),
        (lambda: generate_probe("solidity", "color", 0), "valid probe variant"),
    ],
)
def test_unknown_names_list_the_valid_ones(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_different_seeds_render_different_clips():
    a = generate_clip("solidity", "example", 11)["frames"].numpy()
    b = generate_clip("solidity", "example", 12)["frames"].numpy()
    assert not np.array_equal(a, b)


#: Each concept's balanced pools: the two halves of each of its quadruplets (unchangeableness:
#: one per change), tested by the quadruplet row.
BALANCED_POOLS = [
    (concept, row, halves)
    for concept, quadruplets in specs.QUADRUPLETS.items()
    for row, halves in quadruplets.items()
]


@pytest.mark.parametrize("concept,row,halves", BALANCED_POOLS)
def test_balanced_pools_have_no_frame_local_cue(concept, row, halves):
    """A physics-blind score must not tell inconsistent from consistent videos in a pool:
    |d_z| <= 0.25 and accuracy (ties half) in [0.3, 0.7] for every frame-local cue."""
    per_variant = max(2, FAIRNESS_PAIRS // len(halves))
    records = [
        generate_probe(concept, variant, seed)
        for seed in range(900_000, 900_000 + per_variant)
        for variant in halves  # a seed's halves one after the other: its quadruplet drawn once
    ]
    audit = cues.audit_records(records)
    rows = {r["cue"]: r for r in audit.rows(alpha=ALPHA) if r["variant"] == row}
    for cue in video_cues.FRAME_LOCAL_CUES:
        result = rows[cue]
        d_z = 0.0 if np.isnan(result["d_z"]) else result["d_z"]  # NaN: every pair tied
        assert abs(d_z) <= 0.25 and 0.3 <= result["accuracy"] <= 0.7, (
            f"{concept} {row}: {cue} separates the pairs (d_z={d_z:+.2f}, "
            f"accuracy={result['accuracy']:.2f}, n={result['n']})"
        )


def _cameras(records) -> np.ndarray:
    return np.stack([record["camera"][0].numpy() for record in records]).astype(np.float64)


@pytest.mark.parametrize("concept", CONCEPTS)
def test_one_camera_distribution_per_concept(concept):
    """Examples, every control and the probes draw the camera from the concept's CAMERA range;
    each control's cameras are distributed as the examples' (two-sample KS per parameter)."""
    camera_range = concept_scene(concept).CAMERA
    kinds = CLIP_KINDS_BY_CONCEPT[concept]
    cameras = {
        kind: _cameras([generate_clip(concept, kind, seed) for seed in range(CAMERA_CLIPS)])
        for kind in kinds
    }
    for variant in PROBE_VARIANTS[concept]:
        cameras[f"probe {variant}"] = _cameras(
            [generate_probe(concept, variant, seed) for seed in range(max(NUM_SEEDS, 5))]
        )
    for name, poses in cameras.items():
        for pose in poses:
            assert camera_range.contains(pose), (
                f"{concept} {name}: camera {np.round(pose, 3).tolist()} outside the concept's "
                f"camera range {camera_range.ranges()}"
            )
    for kind in kinds[1:]:
        for index, parameter in enumerate(camera_range.ranges()):
            a, b = cameras["example"][:, index], cameras[kind][:, index]
            if np.ptp(np.concatenate([a, b])) == 0:
                continue
            p = stats.ks_2samp(a, b).pvalue
            assert p > 1e-3, f"{concept} {kind}: camera {parameter} not distributed as examples'"
