"""The verdict is calibrated (docs/architecture.md §8): on synthetic surprise made of the real cue
scores of generated probes (``voe_lightning.audit.calibration``), a model with no physics says VOE in at
most alpha of repetitions per concept, whether it is noise or follows a frame-local cue linearly or
not, wherever the stimuli let any test tell it apart; its power at a true effect is the
noncentral t's. Probes are few and small (30 pairs per variant, 32x32) for a 2-core CPU."""

import json

import numpy as np
import pytest
from helpers import ALPHA
from scipy import stats

from voe_lightning import specs
from voe_lightning.audit import calibration, cue_followers, cues, video_cues
from voe_lightning.scenes import generate_probe

PAIRS, SIZE, REPETITIONS = 30, 32, 2000


@pytest.fixture(scope="module")
def audit():
    records = [
        generate_probe(concept, variant, 910_000 + seed, height=SIZE, width=SIZE)
        for concept, variants in specs.STANDARD_VARIANTS.items()
        for seed in range(PAIRS)
        for variant in variants
    ]  # a seed's halves one after the other: drawn once
    return cues.audit_records(records)


@pytest.fixture(scope="module")
def rows(audit):
    return calibration.calibrate(
        audit, repetitions=REPETITIONS, deltas=np.zeros(1), power_weights=(), alpha=ALPHA
    )


def _describe(row) -> str:
    return (
        f"{row.concept}: {row.follower} of {row.cue}, sign {row.sign:+d}, weight "
        f"{row.weight:g}: false VOE {100 * row.false_voe_rate:.2f}%"
    )


@pytest.mark.parametrize("concept", specs.CONCEPTS)
@pytest.mark.slow
def test_false_voe_stays_at_alpha_for_noise_and_every_cue_follower_the_stimuli_can_expose(
    rows, concept
):
    """Every (cue, follower, sign, weight) whose cue term is not positive in every variant:
    the verdict must say VOE in at most alpha of repetitions, within the binomial error of
    REPETITIONS over all the rates at once (Bonferroni, p = .001)."""
    bound = calibration.false_voe_bound(REPETITIONS, ALPHA, tests=len(rows))
    mine = [row for row in rows if row.concept == concept]
    checked = [row for row in mine if not row.right_on_every_variant]
    assert mine[0].cue is None and mine[0].pairs == PAIRS  # noise alone comes first
    assert len(checked) >= len(video_cues.FRAME_LOCAL_CUES) * 2 * len(calibration.WEIGHTS)
    worst = max(checked, key=lambda row: row.false_voe_rate)
    assert worst.false_voe_rate <= bound, _describe(worst) + f" > bound {100 * bound:.2f}%"


@pytest.mark.parametrize("concept", specs.CONCEPTS)
def test_no_cue_follower_gets_false_voe_beyond_alpha(rows, concept):
    """Also the followers the stimuli favour in every variant (``right_on_every_variant``):
    no test of d can tell those from VOE, so they show where the scenes must change. Every
    concept is tested over quadruplets (unchangeableness one per change), which hold every
    follower of the scores of frames from m on to its noise by construction; continuity, before
    its quadruplets, let level followers through in 55-100% of repetitions."""
    bound = calibration.false_voe_bound(REPETITIONS, ALPHA, tests=len(rows))
    mine = [row for row in rows if row.concept == concept]
    offenders = [_describe(row) for row in mine if row.false_voe_rate > bound]
    assert all(row.right_on_every_variant for row in mine if row.false_voe_rate > bound)
    assert not offenders, offenders


def test_power_of_noise_alone_is_the_noncentral_t():
    """Unchangeableness' verdict needs each of its three quadruplets (one per change) to pass:
    at effect delta its rate is the quadruplet test's (D ~ N(2 delta, 2): the noncentral t,
    df n - 1, nc delta sqrt(2 n)), cubed, both halves nearly always above 0 there (a single
    quadruplet's: test_quadruplet_concepts_calibrate_over_quadruplets...)."""
    n, repetitions = 20, 4000
    deltas = np.array([0.0, 0.5, 0.9])
    noise = {variant: np.zeros(1) for variant in specs.STANDARD_VARIANTS["unchangeableness"]}
    rates = calibration.verdict_rates(
        noise, "unchangeableness", n, repetitions, ALPHA, deltas, np.random.default_rng(1)
    )
    critical = stats.t.ppf(1 - ALPHA, n - 1)
    expected = stats.nct.sf(critical, n - 1, deltas * np.sqrt(2 * n)) ** 3
    error = 4 * np.sqrt(np.maximum(expected * (1 - expected), 1 / repetitions) / repetitions)
    assert np.all(np.abs(rates - expected) <= error + 0.01), (rates, expected)


def test_quadruplet_concepts_calibrate_over_quadruplets_and_cancel_post_change_cues(audit):
    """A quadruplet concept is tested over quadruplets: its noise-only rate at delta is the
    noncentral t's of D (each half delta + N(0, 1): D ~ N(2 delta, 2)), both halves nearly
    always above 0 there; and a follower of a frame-local cue (each reads frames from m on
    only) has exactly opposite terms in a quadruplet's two halves."""
    n, repetitions = 20, 4000
    deltas = np.array([0.0, 0.6])
    rates = calibration.quadruplet_voe(
        [np.zeros(1), np.zeros(1)], n, repetitions, ALPHA, deltas, np.random.default_rng(4)
    ).mean(axis=1)
    assert rates[0] <= calibration.false_voe_bound(repetitions, ALPHA)
    expected = stats.nct.sf(stats.t.ppf(1 - ALPHA, n - 1), n - 1, 0.6 * np.sqrt(2 * n))
    assert abs(rates[1] - expected) <= 4 * np.sqrt(expected * (1 - expected) / repetitions) + 0.01
    for concept, quadruplets in specs.QUADRUPLETS.items():
        for cue in video_cues.FRAME_LOCAL_CUES:
            for follower in cue_followers.FOLLOWERS:
                terms = calibration.cue_terms(audit, concept, cue, follower)
                for halves in quadruplets.values():
                    first, second = (terms[half] for half in halves)
                    assert first.size == PAIRS and np.array_equal(first, -second), (
                        concept,
                        halves,
                        cue,
                        follower,
                    )


def test_calibration_is_seeded_and_refuses_bad_arguments(audit):
    options = dict(
        repetitions=50, concepts=["solidity"], followers=["linear"], weights=(1.0,), seed=3
    )
    first = calibration.calibrate(audit, alpha=ALPHA, **options)
    assert first == calibration.calibrate(audit, alpha=ALPHA, **options)
    assert first[0].delta_80 is not None and first[1].delta_80 is not None  # power at weight 1
    table = calibration.calibration_markdown(first)
    assert "| solidity | 30 | linear |" in table and "(α = 0.01, 50 repetitions)" in table
    with pytest.raises(ValueError, match=r"unknown followers \['cubic'\]; valid: linear"):
        calibration.calibrate(audit, followers=["cubic"], alpha=ALPHA)
    with pytest.raises(ValueError, match="alpha must be a significance level"):
        calibration.calibrate(audit, alpha=0)


def test_analyze_calibrate_prints_and_writes_the_table_of_a_store(tmp_path, capsys):
    from voe_lightning.cli import main
    from voe_lightning.data.store import generate_dataset

    root = tmp_path / "store"
    generate_dataset(
        root,
        concepts=["object_persistence"],
        train_examples=0,
        val_pairs=4,
        test_pairs=0,
        generalization_pairs=0,
        workers=1,
        num_frames=8,
        height=32,
        width=32,
        progress=False,
    )
    capsys.readouterr()
    out = tmp_path / "calibration.md"
    table = main(
        [
            "analyze",
            "calibrate",
            "--root",
            str(root),
            "--split",
            "val",
            "--repetitions",
            "40",
            "--progress",
            "false",
            "--out",
            str(out),
        ]
    )
    assert table == capsys.readouterr().out == out.read_text()
    assert f"## Calibration on the val pairs of {root} (α = 0.01, 40 repetitions)" in table
    assert table.count("| object_persistence | 4 |") == len(cue_followers.FOLLOWERS)
    rows = json.loads(out.with_suffix(".json").read_text())
    assert {row["concept"] for row in rows} == {"object_persistence"} and rows[0]["cue"] is None
