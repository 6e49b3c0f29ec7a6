"""IntPhys 2 reader on tiny mp4 fixtures in the released layout (rows shuffled, every principle,
both prefixes, Debug's ``filename`` column, Held-Out without labels): pairing, decoding, every
bad-input error, the metrics against a hand computation, and ``test``/``predict`` through the
CLI with the parameter-free CueScorer and no checkpoint."""

import csv
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch
import yaml
from helpers import ALPHA
from helpers.intphys2 import PREFIXES, SCENES, SIZE, frame, make_root, write_metadata
from helpers.locations import REPO
from helpers.quadruplets import check_quadruplet_rows

from voe_lightning.benchmarks.evaluation import VIDEO_COLUMNS, external_metrics
from voe_lightning.benchmarks.intphys2.datamodule import IntPhys2DataModule
from voe_lightning.benchmarks.metrics import intphys2_metrics
from voe_lightning.benchmarks.reader import BenchmarkDataError
from voe_lightning.cli import main

#: num_frames=4 spread over 8 frames samples source frames [0, 2, 5, 7].
SAMPLED = [0, 2, 5, 7]
CONFIG = str(REPO / "configs" / "intphys2.yaml")


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return make_root(tmp_path_factory.mktemp("intphys2"))


def datamodule(root, **options):
    settings = dict(root=str(root), num_frames=4, height=SIZE, width=SIZE, probe_batch_size=3)
    return IntPhys2DataModule(**{**settings, **options})


def copy(root, tmp_path):
    shutil.copytree(root, tmp_path / "intphys2")
    return tmp_path / "intphys2"


def test_shuffled_rows_pair_by_scene_and_prefix_for_every_principle(root):
    dm = datamodule(root)
    dm.setup("test")
    table = dm.pairs("Main")
    assert len(table) == 8
    assert sorted({e["principle"] for e in table.values()}) == sorted(
        p for _, p, _, _ in SCENES.values()
    )
    for entry in table.values():
        assert entry["possible"] == f"s{entry['scene']}_{entry['prefix']}_possible"
        assert entry["impossible"] == f"s{entry['scene']}_{entry['prefix']}_impossible"
        assert entry["divergence_frame"] == PREFIXES[entry["prefix"]][3]
    # scenes come in (condition, scene) order whatever the rows' order; a seed names the
    # scene, the variant its pair (standard: prefix 1, counterbalanced: prefix 2)
    assert [
        (seed, variant, table[seed, variant]["condition"], table[seed, variant]["prefix"])
        for seed, variant in sorted(table)
    ][:2] == [
        (0, "counterbalanced", "continuity_swap", "2"),
        (0, "standard", "continuity_swap", "1"),
    ]
    assert {(v, e["prefix"]) for (_, v), e in table.items()} == {
        ("standard", "1"),
        ("counterbalanced", "2"),
    }
    assert sorted({seed for seed, _ in table}) == [0, 1, 2, 3]
    batch = next(iter(dm.test_dataloader()))
    assert batch["consistent", "frames"].shape == (3, 4, SIZE, SIZE, 3)
    for record in batch:
        assert dm.probe_spec().is_in(record)
    entry = table[int(batch["seed"][0]), dm.variant_names[int(batch["variant"][0])]]
    expected = np.stack(
        [
            frame(list(SCENES).index(entry["scene"]), PREFIXES[entry["prefix"]][0], t)
            for t in SAMPLED
        ]
    )
    assert np.array_equal(batch["consistent", "frames"][0].numpy(), expected)  # lossless decode
    assert dm.concept_names[int(batch["concept"][0])] == entry["principle"]
    assert dm.probe_cases() == [
        (p, v)
        for p in sorted(p for _, p, _, _ in SCENES.values())
        for v in ("standard", "counterbalanced")
    ]


def test_debug_filename_column_and_frame_step_of_longer_videos(root):
    dm = datamodule(root, eval_split="Debug", frame_stride=3, first_frame=1)
    dm.setup("test")
    table = dm.pairs("Debug")
    assert len(table) == 2 and {e["difficulty"] for e in table.values()} == {"unspecified"}
    batch = next(iter(dm.test_dataloader()))
    first = table[int(batch["seed"][0]), dm.variant_names[int(batch["variant"][0])]]
    expected = np.stack([frame(7, PREFIXES[first["prefix"]][0], t) for t in (1, 4, 7, 10)])
    assert np.array_equal(batch["consistent", "frames"][0].numpy(), expected)
    with pytest.raises(BenchmarkDataError, match=r"need frame 13, but movies have 12"):
        datamodule(root, eval_split="Debug", frame_stride=4, first_frame=1).setup("test")


def test_cached_pairs_are_served_without_decoding(root, tmp_path, monkeypatch):
    first = datamodule(root, cache_dir=str(tmp_path))
    first.setup("test")
    monkeypatch.setattr("voe_lightning.benchmarks.intphys2.reader.read_video", None)  # would fail
    second = datamodule(root, cache_dir=str(tmp_path))
    second.setup("test")
    assert second.pairs("Main") == first.pairs("Main")
    a, b = next(iter(first.test_dataloader())), next(iter(second.test_dataloader()))
    assert torch.equal(a["inconsistent", "frames"], b["inconsistent", "frames"])


def _edit_main(root, edit):
    path = root / "Main" / "metadata.csv"
    rows = list(csv.DictReader(open(path, newline="")))
    write_metadata(root / "Main", edit(rows))


@pytest.mark.parametrize(
    "case, reason, message",
    [
        (
            "malformed_group",
            "malformed_group",
            r"scene 3 \(permanence\), prefix 1: 2 Possible and 1 Impossible videos \(line \d+ ",
        ),
        (
            "missing_file",
            "missing_file",
            r"metadata.csv, line \d+: file_name 'gone.mp4' names .*gone",
        ),
        ("unlisted_file", "unlisted_file", r"extra.mp4 has no row in .*metadata.csv"),
        ("unknown_condition", "unknown_condition", r"line \d+: unknown condition 'gravity'"),
        ("unknown_type", "unknown_type", r"line \d+: unknown type '3_Possible'"),
        ("undecodable", "undecodable_video", r"s25_2_possible.mp4 does not decode"),
        ("symlink_loop", "bad_path", r"loop.mp4 cannot be resolved .*points back at itself"),
    ],
)
def test_bad_input_raises_naming_it_or_is_skipped_and_counted_when_lenient(
    root, tmp_path, case, reason, message
):
    data = copy(root, tmp_path)
    videos = data / "Main" / "Videos"
    if case == "malformed_group":
        shutil.copy(videos / "s3_1_possible.mp4", videos / "s3_1_again.mp4")
        _edit_main(
            data,
            lambda rows: (
                rows
                + [
                    {
                        **next(r for r in rows if r["name"] == "s3_1_possible"),
                        "name": "again",
                        "file_name": "s3_1_again.mp4",
                    }
                ]
            ),
        )
    elif case == "missing_file":
        _edit_main(data, lambda rows: rows + [{**rows[0], "name": "gone", "file_name": "gone.mp4"}])
    elif case == "unlisted_file":
        shutil.copy(videos / "s3_1_possible.mp4", videos / "extra.mp4")
    elif case == "unknown_condition":
        _edit_main(
            data,
            lambda rows: [
                {**r, "condition": "gravity"} if r["SceneIndex"] == "25" else r for r in rows
            ],
        )
    elif case == "unknown_type":
        _edit_main(
            data,
            lambda rows: [
                {**r, "type": "3_Possible"}
                if r["type"] == "1_Possible" and r["SceneIndex"] == "25"
                else r
                for r in rows
            ],
        )
    elif case == "symlink_loop":
        (videos / "loop.mp4").symlink_to(videos / "loop.mp4")
    else:
        (videos / "s25_2_possible.mp4").write_bytes(b"not a video")
    with pytest.raises(BenchmarkDataError, match=message) as error:
        datamodule(data).setup("test")
    assert error.value.reason == reason
    dm = datamodule(data, lenient=True)
    dm.setup("test")
    assert dm.skipped.get(reason) == (4 if case == "unknown_condition" else 1)  # 4 rows
    # the rest is kept: the scene's other pair (a video that does not decode loses its scene
    # whole: the scene is decoded as one quadruplet) and every other scene
    lost = {
        "malformed_group": 1,
        "missing_file": 0,
        "unlisted_file": 0,
        "symlink_loop": 0,
        "unknown_condition": 2,
        "unknown_type": 1,
        "undecodable": 2,
    }[case]
    assert len(dm.probes("Main")) == 8 - lost
    if case == "unknown_type":  # its scene and prefix now hold only an Impossible
        assert dm.skipped["malformed_group"] == 1


def test_bad_arguments_and_missing_splits_name_the_valid_choices(root, tmp_path):
    with pytest.raises(ValueError, match=r"eval_split must be one of Debug, Main, HeldOut"):
        datamodule(root, eval_split="main")
    with pytest.raises(ValueError, match=r"'HeldOut' has no labels"):
        datamodule(root, eval_split="HeldOut")
    with pytest.raises(FileNotFoundError, match=r"no IntPhys 2 Main split at .*expected"):
        datamodule(tmp_path).setup("test")
    (tmp_path / "Main").mkdir()
    (tmp_path / "Main" / "metadata.csv").write_text("a,b\n1,2\n")
    with pytest.raises(BenchmarkDataError, match=r"has columns \['a', 'b'\]; expected file_name"):
        datamodule(tmp_path).setup("test")


def test_metrics_match_a_hand_computation(root):
    """Per-frame surprise per (principle, prefix): prefix 1 pairs as below, prefix 2 pairs all
    possible [0, 0, 0, 0] vs impossible [0, 0, 0, 1] (right by mean and max)."""
    prefix_1 = {  # possible, impossible
        "Permanence": ([0, 1, 0, 1], [0, 0, 3, 0]),  # mean right, max right
        "Immutability": ([2, 2, 2, 2], [0, 0, 0, 4]),  # mean wrong, max right
        "Continuity": ([1, 1, 1, 1], [1, 1, 1, 1]),  # ties
        "Solidity": ([0, 0, 0, 5], [0, 2, 0, 0]),  # both wrong
    }
    dm = datamodule(root)
    table = dm.pairs("Main")
    seeds = sorted(table)
    sides = [
        prefix_1[table[s]["principle"]]
        if table[s]["prefix"] == "1"
        else ([0, 0, 0, 0], [0, 0, 0, 1])
        for s in seeds
    ]
    outputs = {
        "seed": np.array([seed for seed, _ in seeds]),
        "variant": np.array([dm.variant_names.index(v) for _, v in seeds]),
        "surprise_consistent": np.array([p for p, _ in sides], np.float32),
        "surprise_inconsistent": np.array([i for _, i in sides], np.float32),
    }
    report = external_metrics(dm.external_pairs(), outputs, bootstrap=0, alpha=ALPHA)
    metrics = report["metrics"]
    # possible maxima {1, 2, 1, 5, 0, 0, 0, 0}: 90th percentile at 0.9 * 7 = 6.3 -> 2 + 0.3 * 3
    assert metrics["threshold"]["value"] == pytest.approx(2.9)
    overall = metrics["all"]
    assert overall["n_pairs"] == 8
    assert overall["relative_accuracy_mean"] == pytest.approx((1 + 0 + 0.5 + 0 + 4) / 8)
    assert overall["relative_accuracy_max"] == pytest.approx((1 + 1 + 0.5 + 0 + 4) / 8)
    assert overall["ties_mean"] == overall["ties_max"] == 1
    # possible right: 7 of 8 (max 5 > 2.9); impossible right: 3 and 4 only
    assert overall["absolute_accuracy"] == pytest.approx((7 + 2) / 16)
    # impossible maxima {3, 4, 1, 2, 1, 1, 1, 1} over possible {1, 2, 1, 5, 0, 0, 0, 0}
    assert overall["auroc_max"] == pytest.approx((7 + 7 + 5 + 6.5 + 4 * 5) / 64)
    assert overall["paired_test"]["n"] == 8
    immutability = metrics["principle"]["Immutability"]
    assert immutability["relative_accuracy_mean"] == 0.5
    assert immutability["relative_accuracy_max"] == 1.0
    assert immutability["absolute_accuracy"] == 0.75  # possible 2, 0 right; impossible 4 only
    assert set(metrics["principle_difficulty_camera"]) == {
        "/".join((p, d, c)) for _, p, d, c in SCENES.values()
    }
    assert metrics["principle_difficulty_camera"]["Solidity/Hard/Moving"]["n_pairs"] == 2
    same = intphys2_metrics(
        *zip(*[(table[s]["principle"], table[s]["difficulty"], table[s]["camera"]) for s in seeds]),
        outputs["surprise_consistent"],
        outputs["surprise_inconsistent"],
        bootstrap=0,
        alpha=ALPHA,
    )
    assert same["all"] == overall


def _run(root, tmp_path, subcommand, *extra):
    return main(
        [
            subcommand,
            "--config",
            CONFIG,
            *extra,
            "--model",
            "voe_lightning.model.CueScorer",
            "--model.init_args.cue",
            "motion",
            "--data.init_args.root",
            str(root),
            "--data.init_args.num_frames",
            "4",
            "--data.init_args.height",
            str(SIZE),
            "--data.init_args.width",
            str(SIZE),
            "--data.init_args.num_workers",
            "0",
            "--data.init_args.cache_dir",
            "null",
            "--trainer.logger.init_args.save_dir",
            str(tmp_path / "runs"),
            "--trainer.enable_progress_bar",
            "false",
        ]
    )


def test_cue_scorer_runs_test_and_predict_without_a_checkpoint(root, tmp_path):
    _run(root, tmp_path, "test")
    report = tmp_path / "runs" / "intphys2" / "version_0" / "voe_report"
    metrics = json.loads((report / "benchmark_metrics.json").read_text())
    assert metrics["benchmark"] == "IntPhys 2" and metrics["metrics"]["all"]["n_pairs"] == 8
    rows = list(csv.DictReader(open(report / "videos.csv")))
    assert tuple(rows[0]) == VIDEO_COLUMNS and len(rows) == 16
    by_name = {row["name"]: row for row in rows}
    # motion per frame: the impossible video's object jumps once, so its max exceeds the possible's
    for prefix in PREFIXES:
        assert float(by_name[f"s25_{prefix}_impossible"]["surprise_max"]) > float(
            by_name[f"s25_{prefix}_possible"]["surprise_max"]
        )
    assert {row["label"] for row in rows} == {"possible", "impossible"}
    # the physics-blind baselines' rows stand beside the model's, on the same pairs
    blind = list(csv.DictReader(open(report / "cues.csv")))
    assert {row["cue"] for row in blind} >= {
        "motion_energy",
        "copy_last_error",
        "linear_extrapolation_error",
        "pixel_novelty",
    }
    motion = {
        (row["concept"], row["variant"]): int(row["n"])
        for row in blind
        if row["cue"] == "motion_energy" and row["variant"] in ("standard", "counterbalanced")
    }
    assert motion == {
        (principle, variant): 1
        for _, principle, _, _ in SCENES.values()
        for variant in ("standard", "counterbalanced")
    }

    config = tmp_path / "heldout.yaml"
    jsonl = tmp_path / "heldout.jsonl"
    config.write_text(
        yaml.safe_dump(
            {
                "trainer": {
                    "callbacks+": [
                        {
                            "class_path": "voe_lightning.callbacks.prediction_writer.IntPhys2LeaderboardWriter",
                            "init_args": {
                                "threshold": str(report / "benchmark_metrics.json"),
                                "path": str(jsonl),
                            },
                        }
                    ]
                }
            }
        )
    )
    _run(root, tmp_path, "predict", "--config", str(config))
    lines = [json.loads(line) for line in jsonl.read_text().splitlines()]
    assert [line["row_id"] for line in lines] == [
        f"s25_{p}_{k}" for p in PREFIXES for k in ("possible", "impossible")
    ]
    assert all(
        line["model_answer"] in (0, 1)
        and line["data_name"] == "IntPhys2"
        and line["task"] == "HeldOut"
        for line in lines
    )


@pytest.mark.slow
def test_the_package_and_its_datamodules_import_without_pyav():
    """PyAV is needed only to decode IntPhys 2's videos: a machine that trains on generated data
    (a lent GPU with no package index, say) must start without it."""
    blocked = (
        "import sys; sys.modules['av'] = None; "
        "import voe_lightning.cli, voe_lightning.datamodules, voe_lightning.benchmarks.intphys2"
    )
    root = REPO
    result = subprocess.run(
        [sys.executable, "-c", blocked],
        cwd=root,
        capture_output=True,
        text=True,
        check=False,
        env={**os.environ, "PYTHONPATH": str(root)},
    )
    assert result.returncode == 0, result.stderr


def test_a_report_tests_each_scenes_two_pairs_together(root):
    """Issue 48 part 2: a scene's two pairs share its seed and are its halves, so the report
    gives each principle a quadruplet row over its scenes (here one each: a row without a test,
    and an undecided verdict) beside the per-pair rows."""
    dm = datamodule(root)
    dm.setup("test")
    probes = torch.cat(list(dm.test_dataloader()))
    check_quadruplet_rows(
        probes,
        dm.concept_names,
        dm.variant_names,
        {principle: 1 for _, principle, _, _ in SCENES.values()},
    )
