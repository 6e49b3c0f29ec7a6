"""The cue audit: each physics-blind scorer on hand-built videos with known answers, rows equal
to scipy's paired t-test on the cue scores, pooled rows over the union of both variants, ties
counted half, mask-less pairs skipped with a note, and ``python -m voe_lightning audit`` on a
tiny generated store."""

import csv
import dataclasses
import json

import numpy as np
import pytest
import torch
from helpers import ALPHA
from scipy import stats
from tensordict import TensorDict

from voe_lightning import specs
from voe_lightning.audit import cue_report, cues, video_cues
from voe_lightning.cli import main
from voe_lightning.data.store import generate_dataset

T, H, W = 6, 16, 16


def _score(frames, mask=None, m=2):
    frames = torch.as_tensor(np.asarray(frames, np.uint8))[None]
    mask = None if mask is None else torch.as_tensor(np.asarray(mask, np.uint8))[None]
    return {
        cue: float(value[0])
        for cue, value in video_cues.score_videos(frames, mask, torch.tensor([m])).items()
    }


def _square_appears(at):
    """Grey background; a white 4x4 square (mask id 1) from frame ``at`` on."""
    frames = np.full((T, H, W, 3), 100, np.uint8)
    mask = np.zeros((T, H, W), np.uint8)
    frames[at:, 4:8, 4:8] = 255
    mask[at:, 4:8, 4:8] = 1
    return frames, mask


def test_a_square_appearing_after_m_raises_foreground_and_novelty():
    empty = _score(*_square_appears(T))  # never appears
    appears = _score(*_square_appears(4))
    assert empty == {cue: 0.0 for cue in video_cues.CUES}
    assert appears["foreground_pixels"] == 16 * (T - 4)  # frames 4 and 5
    # New at frame 4 only: L1 over RGB of (255 - 100) / 255 on 16 pixels; frame 5 saw it at 4.
    assert appears["pixel_novelty"] == pytest.approx(16 * 3 * 155 / 255, rel=1e-6)
    assert appears["motion_energy"] > 0 and appears["copy_last_error"] > 0


def test_nothing_at_or_before_the_manipulation_frame_counts():
    scores = _score(*_square_appears(2), m=2)  # appears at m: the same in both videos of a pair
    assert scores["motion_energy"] == scores["copy_last_error"] == scores["pixel_novelty"] == 0.0
    assert scores["foreground_pixels"] == 16 * (T - 3)  # frames after m only


def test_static_video_has_no_motion_and_linear_change_no_extrapolation_error():
    static = _score(np.full((T, H, W, 3), 77, np.uint8))
    assert static["motion_energy"] == static["copy_last_error"] == 0.0
    assert static["linear_extrapolation_error"] == static["pixel_novelty"] == 0.0
    ramp = np.broadcast_to((20 + 30 * np.arange(T))[:, None, None, None], (T, H, W, 3))
    linear = _score(ramp.astype(np.uint8), m=1)
    step = 30 / 255
    assert linear["copy_last_error"] == pytest.approx((T - 2) * step**2, rel=1e-5)
    assert linear["motion_energy"] == pytest.approx((T - 2) * step, rel=1e-5)
    assert linear["linear_extrapolation_error"] == pytest.approx(0.0, abs=1e-10)


def test_score_videos_refuses_bad_shapes_and_frames():
    with pytest.raises(ValueError, match=r"\[B, T, H, W, 3\]"):
        video_cues.score_videos(torch.zeros(T, H, W, 3, dtype=torch.uint8), None, torch.tensor([1]))
    with pytest.raises(ValueError, match=r"in \[0, 5\], got \[6\]"):
        video_cues.score_videos(
            torch.zeros(1, T, H, W, 3, dtype=torch.uint8), None, torch.tensor([6])
        )


def _pair(concept, variant, seed, masks=True):
    """Consistent: the square appears at frame 3; inconsistent: at frame 3 + seed % 4 (6 is
    never), with noise so no two pairs are alike."""
    rng = np.random.default_rng(seed)
    consistent, mask = _square_appears(3)
    inconsistent, inconsistent_mask = _square_appears(3 + seed % 4)
    inconsistent = np.clip(inconsistent + rng.integers(0, 3, inconsistent.shape), 0, 255)
    if not masks:
        mask, inconsistent_mask = np.zeros_like(mask), np.zeros_like(mask)

    def video(f, k):
        return {"frames": torch.from_numpy(f.astype(np.uint8)), "mask": torch.from_numpy(k)}

    return TensorDict(
        {
            "consistent": video(consistent, mask),
            "inconsistent": video(inconsistent, inconsistent_mask),
            "concept": torch.tensor(specs.CONCEPTS.index(concept)),
            "variant": torch.tensor(specs.VARIANTS.index(variant)),
            "manipulation_frame": torch.tensor(2),
            "seed": torch.tensor(seed),
        },
        batch_size=[],
    )


@pytest.fixture(scope="module")
def audit():
    records = [
        _pair("object_persistence", v, 10 * i + s)
        for i, v in enumerate(["standard", "counterbalanced"])
        for s in range(6)
    ]
    records += [_pair("unchangeableness", "color", 100 + s, masks=False) for s in range(5)]
    return cues.audit_records(records, batch_size=4)


def test_rows_agree_with_scipy_and_pool_both_variants_stratified(audit):
    """Variant rows are scipy's paired test; the pooled row, as the model's, is the stratified
    test of both variants: scipy's Welch test of d_standard against -d_counterbalanced."""
    rows = {(r["concept"], r["variant"], r["cue"]): r for r in audit.rows(alpha=ALPHA)}
    assert [(c, v) for c, v, _ in audit.groups()] == [
        ("object_persistence", "standard"),
        ("object_persistence", "counterbalanced"),
        ("object_persistence", "pooled"),
        ("unchangeableness", "color"),
    ]
    persistence = audit.concepts == "object_persistence"
    standard = persistence & (audit.variants == "standard")
    counterbalanced = persistence & (audit.variants == "counterbalanced")
    for cue in ("motion_energy", "pixel_novelty"):
        d = audit.scores["inconsistent"][cue] - audit.scores["consistent"][cue]
        for variant, selected in [("standard", standard), ("counterbalanced", counterbalanced)]:
            reference = stats.ttest_1samp(d[selected], 0.0, alternative="greater")
            row = rows[("object_persistence", variant, cue)]
            assert row["n"] == selected.sum() == 6
            assert row["t"] == pytest.approx(reference.statistic, rel=1e-10)
            assert row["p_value"] == pytest.approx(reference.pvalue, rel=1e-8)
            two_sided = stats.ttest_1samp(d[selected], 0.0).pvalue
            assert row["p_two_sided"] == pytest.approx(two_sided, rel=1e-8)
        pooled = rows[("object_persistence", "pooled", cue)]
        welch = stats.ttest_ind(d[standard], -d[counterbalanced], equal_var=False)
        assert pooled["n"] == 12
        assert pooled["t"] == pytest.approx(welch.statistic, rel=1e-10)
        assert pooled["p_two_sided"] == pytest.approx(welch.pvalue, rel=1e-8)
        assert pooled["relative_surprise"] == pytest.approx(
            (d[standard].mean() + d[counterbalanced].mean()) / 2, rel=1e-12
        )


def test_accuracy_counts_ties_half(audit):
    rows = {(r["concept"], r["variant"], r["cue"]): r for r in audit.rows(alpha=ALPHA)}
    d = (
        audit.scores["inconsistent"]["foreground_pixels"]
        - audit.scores["consistent"]["foreground_pixels"]
    )[audit.variants == "standard"]
    assert (d == 0).any() and (d < 0).any()  # some pairs tie: the square appears at 3 in both
    expected = np.mean(d > 0) + 0.5 * np.mean(d == 0)
    assert rows[("object_persistence", "standard", "foreground_pixels")]["accuracy"] == expected


def test_pairs_without_masks_skip_the_mask_cue_with_a_note(audit, tmp_path):
    rows = [r for r in audit.rows(alpha=ALPHA) if r["concept"] == "unchangeableness"]
    skipped = {r["cue"]: r for r in rows}["foreground_pixels"]
    assert skipped["t"] is None and "no object mask" in skipped["note"] and skipped["n"] == 5
    assert all(r["t"] is not None for r in rows if r["cue"] != "foreground_pixels")
    cue_report.write_audit(audit.rows(alpha=ALPHA), tmp_path)
    markdown = (tmp_path / "cues.md").read_text()
    assert "| unchangeableness | color | 5 | n/a |" in markdown
    assert "unchangeableness/color, foreground: foreground_pixels skipped" in markdown


def test_model_correlations_agree_with_scipy_and_expose_a_cue_follower(audit, tmp_path):
    """A 'model' whose relative surprise is the motion cue's d plus noise has r near 1 with
    that cue in every group, the pooled one too; r agrees with scipy.stats.pearsonr."""
    motion = (
        audit.scores["inconsistent"]["motion_energy"] - audit.scores["consistent"]["motion_energy"]
    )
    follower = 3.0 * motion + np.random.default_rng(0).normal(0.0, 1e-3, len(audit))
    rows = {
        (r["concept"], r["variant"], r["cue"]): r
        for r in audit.model_correlations(follower, alpha=ALPHA)
    }
    for concept, variant, selected in audit.groups():
        row = rows[(concept, variant, "motion_energy")]
        reference = stats.pearsonr(follower[selected], motion[selected])
        assert row["r"] == pytest.approx(reference.statistic, rel=1e-10) and row["r"] > 0.99
        assert row["p_two_sided"] == pytest.approx(reference.pvalue, rel=1e-6)
    # No masks, no foreground score: no correlation, with the reason.
    assert rows[("unchangeableness", "color", "foreground_pixels")]["r"] is None
    assert "not scored" in rows[("unchangeableness", "color", "foreground_pixels")]["note"]
    constant = audit.model_correlations(np.ones(len(audit)), alpha=ALPHA)
    assert all(
        r["r"] is None and "constant" in r["note"]
        for r in constant
        if r["concept"] == "object_persistence"
    )
    with pytest.raises(ValueError, match="one value per scored pair"):
        audit.model_correlations(np.ones(3), alpha=ALPHA)
    cue_report.write_audit(audit.rows(alpha=ALPHA), tmp_path, correlation_rows=list(rows.values()))
    markdown = (tmp_path / "cues.md").read_text()
    assert "Does the model's surprise track a cue, pair by pair?" in markdown
    assert "| object_persistence | **pooled** | 12 |" in markdown.split("pair by pair?")[1]
    with open(tmp_path / "cue_correlations.csv", newline="") as handle:
        assert len(list(csv.DictReader(handle))) == len(rows)


def test_the_pooled_correlation_within_variants_is_the_partial_correlation_given_the_variant(audit):
    """A model whose effect is larger in one variant, while pair by pair it follows no cue, has
    a large pooled r with a cue whose mean differs between the variants too, and an r near 0
    within variants; that r is the partial correlation given the variant (the correlation of
    the residuals of regressing both on the variant), its p from t with n - 3 df."""
    motion = (
        audit.scores["inconsistent"]["motion_energy"] - audit.scores["consistent"]["motion_energy"]
    )
    rng = np.random.default_rng(1)
    shift = np.where(audit.variants == "counterbalanced", 1.0, -1.0)
    cue = motion + 100 * shift * motion.std()  # variants far apart in the cue's mean
    scores = {side: dict(values) for side, values in audit.scores.items()}  # the fixture's stay
    scores["inconsistent"]["motion_energy"] = scores["consistent"]["motion_energy"] + cue
    shifted = dataclasses.replace(audit, scores=scores)
    model = 50 * shift + rng.normal(0.0, 1.0, len(audit))  # no pair-by-pair relation
    rows = {
        (r["concept"], r["variant"], r["cue"]): r
        for r in shifted.model_correlations(model, alpha=ALPHA)
    }
    for concept, variant, selected in audit.groups():
        if variant != "pooled":
            continue
        assert rows[(concept, "pooled", "motion_energy")]["r"] > 0.9
        within = rows[(concept, cues.WITHIN_VARIANTS, "motion_energy")]
        design = np.stack(
            [audit.variants[selected] == label for label in np.unique(audit.variants[selected])], 1
        ).astype(float)
        residual = [
            values - design @ np.linalg.lstsq(design, values, rcond=None)[0]
            for values in (model[selected], cue[selected])
        ]
        reference = stats.pearsonr(*residual).statistic
        assert within["r"] == pytest.approx(reference, rel=1e-9) and abs(within["r"]) < 0.7
        df = within["n"] - 3
        t = reference * np.sqrt(df / (1 - reference**2))
        assert within["p_two_sided"] == pytest.approx(2 * stats.t.sf(abs(t), df), rel=1e-9)


def test_seen_extent_counts_object_frames_seen_in_one_video_only():
    """After the manipulation frame (2 of 6): object 1 vanishes at frame 4 and object 2 shows a
    frame early in the inconsistent video of the first pair: 3 object-frames parted, the first
    at frame 3 (0 frames after m + 1), one object-frame fewer seen; the second pair's videos
    are alike: none parted, the 3 frames left, none more seen."""
    consistent = torch.zeros(2, 6, 3)
    consistent[:, :, 1] = 0.1
    consistent[:, 4:, 2] = 0.05
    inconsistent = consistent.clone()
    inconsistent[0, 4:, 1] = 0.0
    inconsistent[0, 3, 2] = 0.05
    extent = cues.seen_extent(inconsistent, consistent, torch.tensor([2, 2]))
    np.testing.assert_array_equal(extent, [[3.0, 0.0, -1.0], [0.0, 3.0, 0.0]])


def test_the_physics_perfect_observer_pays_for_what_it_sees_differ():
    """After the manipulation frame (1 of 4): object 0 shows in the inconsistent video alone at
    frame 2 (1); at frame 3 object 1, seen in both, is 0.1 m away (2 STATE_SCALEs) and turned
    0.05 rad about z (1; its quaternion's sign flipped, the same rotation), while object 0,
    hidden in both, is somewhere else (0). The difference at frame 1 is not after m (0)."""

    def objects():
        return {
            "position": torch.zeros(1, 4, 2, 3),
            "visible_fraction": torch.zeros(1, 4, 2),
            "orientation": torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(1, 4, 2, 1),
        }

    consistent, inconsistent = objects(), objects()
    consistent["visible_fraction"][0, :, 1] = 0.1
    inconsistent["visible_fraction"][0, :, 1] = 0.1
    inconsistent["visible_fraction"][0, 2, 0] = 0.05
    inconsistent["position"][0, 1, 1] = torch.tensor([9.0, 0.0, 0.0])
    inconsistent["position"][0, 3, 1] = torch.tensor([0.1, 0.0, 0.0])
    inconsistent["position"][0, 3, 0] = torch.tensor([0.0, 5.0, 0.0])
    half = 0.05 / 2
    inconsistent["orientation"][0, 3, 1] = -torch.tensor([np.cos(half), 0.0, 0.0, np.sin(half)])
    surprise = cues.physics_perfect_surprise(inconsistent, consistent, torch.tensor([1]))
    assert surprise.shape == (1,) and surprise[0] == pytest.approx(4.0, abs=1e-4)
    assert cues.physics_perfect_surprise(consistent, consistent, torch.tensor([1]))[0] == 0.0


def _extent_audit(rng, pairs=200):
    """Object persistence pairs of both variants with a seen extent and a foreground cue that
    counts it in pixels (each object-frame of the violation shows a random 50 to 150 pixels),
    mirrored between the variants; no other cue differs."""
    variants = np.repeat(np.array(["standard", "counterbalanced"], dtype=object), pairs)
    parted = rng.integers(1, 10, 2 * pairs).astype(float)
    first = rng.integers(0, 5, 2 * pairs).astype(float)
    sign = np.where(variants == "standard", -1.0, 1.0)
    extent = np.stack([parted, first, sign * parted], 1)
    foreground = sign * parted * rng.uniform(50, 150, 2 * pairs)
    scores = {side: {cue: np.zeros(2 * pairs) for cue in video_cues.CUES} for side in cues.SIDES}
    scores["inconsistent"]["foreground_pixels"] = foreground
    return cues.CueAudit(
        np.full(2 * pairs, "object_persistence", dtype=object), variants, scores, extent
    ), foreground


def test_given_the_seen_extent_a_model_that_sees_the_violation_grow_follows_no_cue():
    """A model whose surprise follows the object-frames of the violation it sees (here, how
    many more the inconsistent video shows) correlates with the foreground cue within variants
    (the cue counts the same object-frames in pixels), and not given the seen extent; that r is
    the partial correlation given a regression on the extent within each variant, its p from t
    with n - 1 - 6 df. A model that follows the pixels themselves still does, given the
    extent."""
    rng = np.random.default_rng(3)
    audit, foreground = _extent_audit(rng)
    sees = 3.0 * audit.extent[:, 2] + rng.normal(0.0, 1.0, len(audit))
    rows = {(r["variant"], r["cue"]): r for r in audit.model_correlations(sees, alpha=ALPHA)}
    assert abs(rows[(cues.WITHIN_VARIANTS, "foreground_pixels")]["r"]) > 0.5
    given = rows[(cues.GIVEN_EXTENT, "foreground_pixels")]
    residual = []
    for values in (sees, foreground):
        rest = values.copy()
        for variant in ("standard", "counterbalanced"):
            chosen = audit.variants == variant
            design = np.column_stack([np.ones(int(chosen.sum())), audit.extent[chosen]])
            rest[chosen] -= design @ np.linalg.lstsq(design, values[chosen], rcond=None)[0]
        residual.append(rest)
    reference = stats.pearsonr(*residual).statistic
    assert given["r"] == pytest.approx(reference, rel=1e-9) and abs(given["r"]) < 0.2
    df = len(audit) - 1 - 2 * 3  # per variant a mean and the extent's rank (parted = |seen|)
    t = reference * np.sqrt(df / (1 - reference**2))
    assert given["p_two_sided"] == pytest.approx(2 * stats.t.sf(abs(t), df), rel=1e-9)
    follower = foreground / foreground.std() + rng.normal(0.0, 0.1, len(audit))
    rows = {(r["variant"], r["cue"]): r for r in audit.model_correlations(follower, alpha=ALPHA)}
    assert rows[(cues.GIVEN_EXTENT, "foreground_pixels")]["r"] > 0.5
    assert "within variants, given the seen extent" in cue_report.format_correlations(
        audit.model_correlations(sees, alpha=ALPHA)
    )
    assert not any(
        r["variant"] == cues.GIVEN_EXTENT
        for r in dataclasses.replace(audit, extent=None).model_correlations(sees, alpha=ALPHA)
    )


def test_the_physics_perfect_row_is_the_observers_r_within_variants_whatever_the_model():
    """The reference row correlates the audit's physics-perfect surprise, not the model's, with
    each cue after centring each variant (r as scipy's on the centred values); no row without
    it."""
    rng = np.random.default_rng(4)
    audit, foreground = _extent_audit(rng)
    observer = audit.extent[:, 2] + rng.normal(0.0, 1.0, len(audit))
    audit = dataclasses.replace(audit, physics_perfect=observer)
    centred = []
    for values in (observer, foreground):
        rest = values.copy()
        for variant in ("standard", "counterbalanced"):
            chosen = audit.variants == variant
            rest[chosen] -= values[chosen].mean()
        centred.append(rest)
    reference = stats.pearsonr(*centred).statistic
    for model in (rng.normal(size=len(audit)), foreground):
        rows = {(r["variant"], r["cue"]): r for r in audit.model_correlations(model, alpha=ALPHA)}
        row = rows[(cues.PHYSICS_PERFECT, "foreground_pixels")]
        assert row["r"] == pytest.approx(reference, rel=1e-9) and abs(reference) > 0.3
    assert rows[(cues.WITHIN_VARIANTS, "foreground_pixels")]["r"] == pytest.approx(1.0)
    assert "Physics-perfect observer" in cue_report.format_correlations(rows.values())
    assert not any(
        r["variant"] == cues.PHYSICS_PERFECT
        for r in dataclasses.replace(audit, physics_perfect=None).model_correlations(
            observer, alpha=ALPHA
        )
    )


def test_the_audit_reads_the_seen_extent_from_the_records_objects():
    """Generated probes carry their objects' states, so the audit has each pair's seen extent
    and physics-perfect surprise (of the two videos), in the records' order, across batches."""
    from voe_lightning.scenes import generate_probe

    records = [
        generate_probe("containment", variant, seed, height=32, width=32)
        for variant in ("standard", "counterbalanced")
        for seed in range(2)
    ]
    audit = cues.audit_records(records, batch_size=3)
    expected = np.concatenate(
        [
            cues.seen_extent(
                record["inconsistent"]["objects"]["visible_fraction"][None],
                record["consistent"]["objects"]["visible_fraction"][None],
                record["manipulation_frame"].reshape(1),
            )
            for record in records
        ]
    )
    np.testing.assert_array_equal(audit.extent, expected)
    assert (audit.extent[:, 0] > 0).all()  # the cube shows in one video, not the other
    observer = np.concatenate(
        [
            cues.physics_perfect_surprise(
                record["inconsistent"]["objects"][None],
                record["consistent"]["objects"][None],
                record["manipulation_frame"].reshape(1),
            )
            for record in records
        ]
    )
    np.testing.assert_allclose(audit.physics_perfect, observer, rtol=1e-12)
    assert (audit.physics_perfect >= audit.extent[:, 0]).all()  # and more where states differ


def test_the_report_shows_a_cue_follower_in_its_correlations_and_scatter(audit, tmp_path):
    """write_report with the cue audit of the model's pairs adds the correlation table to
    cues.md, cue_correlations.csv, the r values to cues.json and cue_scatter.png."""
    from voe_lightning.report import ReportInputs, write_report
    from voe_lightning.report.pairs import PairResults

    motion = (
        audit.scores["inconsistent"]["motion_energy"] - audit.scores["consistent"]["motion_energy"]
    )
    noise = np.random.default_rng(0).normal(0.0, 0.05 * motion.std(), len(audit))
    follower = 3.0 * motion + noise
    per_frame = np.zeros((len(audit), 4))
    inconsistent = per_frame.copy()
    inconsistent[:, -1] = follower
    paired = PairResults(
        audit.concepts,
        audit.variants,
        np.arange(len(audit)),
        np.full(len(audit), 2),
        per_frame,
        inconsistent,
    )
    np.testing.assert_allclose(paired.relative_surprise, follower)
    write_report(
        ReportInputs(paired, alpha=ALPHA, cue_audit=audit, bootstrap=0), tmp_path, echo=False
    )
    report = tmp_path / "voe_report"
    assert "pair by pair?" in (report / "cues.md").read_text()
    assert (report / "cue_scatter.png").stat().st_size > 10_000
    correlations = json.loads((report / "cues.json").read_text())["model_correlations"]
    pooled = [r for r in correlations if r["variant"] == "pooled" and r["cue"] == "motion_energy"]
    assert len(pooled) == 1 and pooled[0]["r"] > 0.9
    # `analyze compare` names the cue each verdict row's surprise tracks most.
    from voe_lightning.analysis import comparison

    compared = {
        (r["concept"], r["variant"]): r for r in comparison.comparison_rows([("f", tmp_path)])
    }
    persistence = compared[("object_persistence", "pooled")]
    assert persistence["tracked_cue"] == "motion_energy" and persistence["tracked_cue_r"] > 0.9
    markdown = comparison.comparison_markdown(list(compared.values()))
    assert f"| motion ({persistence['tracked_cue_r']:+.2f}) |" in markdown
    shuffled = PairResults(
        audit.concepts[::-1],
        audit.variants[::-1],
        np.arange(len(audit)),
        np.full(len(audit), 2),
        per_frame,
        inconsistent,
    )
    with pytest.raises(ValueError, match="not the model's pairs in the same order"):
        write_report(
            ReportInputs(shuffled, alpha=ALPHA, cue_audit=audit, bootstrap=0), tmp_path, echo=False
        )


def test_audit_cli_on_a_tiny_generated_store(tmp_path, capsys):
    root = tmp_path / "store"
    # 2 test pairs per variant, 8 frames: with 6 frames (0.5 s apart) unchangeableness' screen
    # is sometimes never down for two frames in a row and its sampler gives up.
    generate_dataset(
        root,
        concepts=["object_persistence", "unchangeableness"],
        train_examples=0,
        val_pairs=4,
        test_pairs=2,
        generalization_pairs=0,
        workers=1,
        num_frames=8,
        height=32,
        width=32,
        progress=False,
    )
    capsys.readouterr()
    out = tmp_path / "out"
    rows = main(
        ["audit", "--root", str(root), "--split", "val", "--progress", "false", "--out", str(out)]
    )
    printed = capsys.readouterr().out
    assert "Cue audit of" in printed and "pooled" in printed and "novelty" in printed
    groups = list(dict.fromkeys((r["concept"], r["variant"], r["n"]) for r in rows))
    assert groups == [
        ("object_persistence", "standard", 4),
        ("object_persistence", "counterbalanced", 4),
        ("object_persistence", "pooled", 8),
        ("object_persistence", "quadruplet", 4),
    ] + [
        ("unchangeableness", v, 4)
        for v in (
            *specs.VERDICT_VARIANTS["unchangeableness"],
            *specs.QUADRUPLETS["unchangeableness"],
        )
    ]
    # The store's seeds match each quadruplet's halves (unchangeableness: one per change): the
    # frame-local cues read frames from m on only, so D = 0 in every one (pixel novelty
    # remembers the frames before m).
    for row in rows:
        if row["variant"] in specs.QUADRUPLET_ROWS and row["cue"] in video_cues.FRAME_LOCAL_CUES:
            assert row["relative_surprise"] == 0.0 and row["accuracy"] == 0.5, row
    with open(out / "cues.csv", newline="") as handle:
        table = list(csv.DictReader(handle))
    assert len(table) == len(groups) * len(video_cues.CUES) and tuple(table[0]) == cues.CUE_COLUMNS
    document = json.loads((out / "cues.json").read_text())
    assert document["split"] == "val" and document["num_pairs"] == 8 + 6 * 4
    assert document["alpha"] == 0.01  # configs/base.yaml's alpha is the command's default
    markdown = (out / "cues.md").read_text()
    assert "| object_persistence | **pooled** | 8 |" in markdown
    assert markdown.startswith("## Cue audit of") and "(α = 0.01)" in markdown.splitlines()[0]
    # Generated records carry object states: the physics-perfect observer's correlations too,
    # the audit's physics_perfect against each cue, per variant and within variants.
    assert "## What does perfect physics correlate with, pair by pair?" in markdown
    with open(out / "physics_perfect_correlations.csv", newline="") as handle:
        observer = {(r["concept"], r["variant"], r["cue"]): r for r in csv.DictReader(handle)}
    assert ("object_persistence", cues.WITHIN_VARIANTS, "motion_energy") in observer
    assert not any(variant == cues.PHYSICS_PERFECT for _, variant, _ in observer)
    scored = cues.audit_split(root, "val")
    chosen = (scored.concepts == "object_persistence") & (scored.variants == "standard")
    motion = (
        scored.scores["inconsistent"]["motion_energy"]
        - scored.scores["consistent"]["motion_energy"]
    )[chosen]
    expected = stats.pearsonr(scored.physics_perfect[chosen], motion).statistic
    row = observer[("object_persistence", "standard", "motion_energy")]
    assert float(row["r"]) == pytest.approx(expected, rel=1e-9)
    assert (
        "physics_perfect_correlations" in document and "physics_perfect_correlations.csv" in printed
    )

    config = tmp_path / "audit.yaml"  # --config: the same arguments from a file
    config.write_text(f"root: {root}\nconcepts: [unchangeableness]\nprogress: false\n")
    only = main(["audit", "--config", str(config)])
    assert {(r["concept"], r["n"]) for r in only} == {("unchangeableness", 2)}  # test split
    assert (root / "cue_audit" / "test" / "cues.md").is_file()  # the default --out
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["audit", "--root", str(root), "--split", "train"])
    assert capsys.readouterr().err == (
        "error: --split: expected one of val, test, generalization, got train\n"
    )
    with pytest.raises(SystemExit):
        main(["audit", "--root", str(root), "--alpha", "1.5"])
    assert (
        "alpha must be a significance level in (0, 1), e.g. 0.01; got 1.5"
        in capsys.readouterr().err
    )
    with pytest.raises(SystemExit):
        main(["audit", "--root", str(tmp_path / "nowhere"), "--progress", "false"])
    assert "no dataset at" in capsys.readouterr().err


def test_the_scatters_pooled_panel_plots_the_pairs_its_r_counts():
    """Continuity's pooled r counts its standard and counterbalanced pairs: its panel plots
    those, not the ``paper`` pairs reported beside."""
    from voe_lightning.report.figures import cue_scatter_figure
    from voe_lightning.report.pairs import PairResults

    records = [
        _pair("continuity", variant, 10 * i + s)
        for i, variant in enumerate(["standard", "counterbalanced", "paper"])
        for s in range(5)
    ]
    scored = cues.audit_records(records, batch_size=8)
    per_frame = np.zeros((len(scored), 4))
    inconsistent = per_frame.copy()
    inconsistent[:, -1] = np.random.default_rng(1).normal(size=len(scored))
    paired = PairResults(
        scored.concepts,
        scored.variants,
        np.arange(len(scored)),
        np.full(len(scored), 2),
        per_frame,
        inconsistent,
    )
    rows = scored.model_correlations(paired.relative_surprise, alpha=ALPHA)
    figure = cue_scatter_figure(paired, scored, rows)
    (panel,) = [ax for ax in figure.axes if ax.get_title().startswith("continuity / pooled")]
    plotted = sum(len(points.get_offsets()) for points in panel.collections)
    assert plotted == 10 == next(r["n"] for r in rows if r["variant"] == "pooled")
    assert {text.get_text() for text in panel.get_legend().get_texts()} == {
        "standard",
        "counterbalanced",
    }
