"""DESIGN.md §4 validity, for every concept and probe variant over several seeds: shared prefix,
hidden manipulation, a real difference afterwards, determinism, and records matching the specs.
Set VOE_VALIDITY_SEEDS to check more seeds (CI uses a few; run with 50 before changing a scene)."""

import os

import numpy as np
import pytest
import torch

from voe_lightning import specs
from voe_lightning.scenes import (
    CLIP_KINDS_BY_CONCEPT,
    CONCEPTS,
    PROBE_VARIANTS,
    generate_clip,
    generate_probe,
)

NUM_SEEDS = int(os.environ.get("VOE_VALIDITY_SEEDS", "3"))
PROBE_CASES = [(c, v) for c in CONCEPTS for v in PROBE_VARIANTS[c]]
CLIP_CASES = [(c, k) for c in CONCEPTS for k in CLIP_KINDS_BY_CONCEPT[c]]


@pytest.mark.parametrize("concept,variant", PROBE_CASES)
def test_probe_pairs_are_valid(concept, variant):
    spec = specs.probe_spec()
    for seed in range(NUM_SEEDS):
        record = generate_probe(concept, variant, seed)
        assert spec.is_in(record), f"{concept}/{variant} seed {seed} does not match the spec"
        assert specs.concept_name(record) == concept and specs.variant_name(record) == variant
        m = int(record["manipulation_frame"])
        consistent, inconsistent = record["consistent"], record["inconsistent"]
        assert torch.equal(consistent["frames"][:m], inconsistent["frames"][:m]), (
            f"{concept}/{variant} seed {seed}: frames differ before manipulation frame {m}"
        )
        ids = [i for i in record["manipulated_ids"].tolist() if i]
        assert ids, "a probe must name the manipulated object ids"
        if concept == "solidity":
            # The penetration is hidden behind the container's front face: whatever of the
            # block shows in the inconsistent video also shows in the consistent one.
            for t in range(m, consistent["mask"].shape[0]):
                for i in ids:
                    extra = (inconsistent["mask"][t] == i) & (consistent["mask"][t] != i)
                    assert extra.sum() <= 2, f"solidity seed {seed}: penetration visible at {t}"
        else:
            for video in (consistent, inconsistent):
                visible = set(video["mask"][m].unique().tolist())
                assert not visible & set(ids), (
                    f"{concept}/{variant} seed {seed}: manipulated ids {ids} visible at "
                    f"manipulation frame {m}"
                )
        assert not torch.equal(consistent["frames"][m:], inconsistent["frames"][m:]), (
            f"{concept}/{variant} seed {seed}: the two videos never differ"
        )


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


def test_different_concepts_use_independent_randomness():
    a = generate_clip("solidity", "example", 11)["frames"].numpy()
    b = generate_clip("solidity", "example", 12)["frames"].numpy()
    assert not np.array_equal(a, b)
