"""IntPhys reader on a tiny fixture in the released layout: loading, shapes, pairing by
divergence, metrics through the DataModule, answer.txt through predict, the cache, and every
bad-input error."""

import json
import re
import shutil
import struct
import tempfile
import warnings
import zlib

import lightning as L
import numpy as np
import pytest
import torch
from helpers import ALPHA
from helpers.intphys import SAMPLED, SCENES, datamodule, make_intphys, make_train
from helpers.quadruplets import check_quadruplet_rows
from PIL import Image

import voe_lightning.benchmarks.intphys.reader as intphys
from voe_lightning import specs
from voe_lightning.benchmarks.evaluation import external_metrics
from voe_lightning.benchmarks.intphys.reader import read_png
from voe_lightning.benchmarks.metrics import read_answer_file, score_answers
from voe_lightning.benchmarks.reader import BenchmarkDataError
from voe_lightning.callbacks.prediction_writer import IntPhysAnswerWriter
from voe_lightning.model import SurpriseModel


def first_sampled_at_or_after(frame: int) -> int:
    return next(k for k, source in enumerate(SAMPLED) if source >= frame)


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("intphys")
    make_intphys(root, "dev", labelled=True)
    make_intphys(root, "test", labelled=False)
    make_train(root)
    return root


def fresh_copy(dataset_root, tmp_path):
    target = tmp_path / "intphys"
    shutil.copytree(dataset_root, target)
    return target


def test_dev_probes_load_with_spec_shapes_and_pairs_recovered_from_divergence(dataset_root):
    dm = datamodule(dataset_root)
    dm.setup("test")
    batches = list(dm.test_dataloader())
    records = torch.cat(batches)
    assert records.batch_size == torch.Size([6])  # 3 scenes x 2 pairs
    spec = dm.probe_spec()
    for record in records:
        assert spec.is_in(record)
    assert records["consistent", "frames"].shape == (6, 5, 16, 16, 3)
    table = dm.quadruplets("dev")
    for q, (scene, (switch_ab, switch_ba, folders)) in enumerate(SCENES.items()):
        entry = table[q]
        assert entry["scene"] == scene and not entry["ambiguous_pairing"]
        found = {(p["possible"], p["impossible"]): p["divergence_frame"] for p in entry["pairs"]}
        assert found == {
            (f"{scene}/{folders[0]}", f"{scene}/{folders[2]}"): first_sampled_at_or_after(
                switch_ab
            ),
            (f"{scene}/{folders[1]}", f"{scene}/{folders[3]}"): first_sampled_at_or_after(
                switch_ba
            ),
        }
    for record in records:
        entry = table[int(record["seed"])]  # a seed names the scene's quadruplet
        pair = entry["pairs"][int(record["variant"])]  # the variant its half
        m = int(record["manipulation_frame"])
        assert m == pair["divergence_frame"]
        con, inc = record["consistent", "frames"], record["inconsistent", "frames"]
        assert torch.equal(con[:m], inc[:m]) and not torch.equal(con[m], inc[m])
        assert dm.concept_names[int(record["concept"])].startswith(entry["block"])
        # the consistent video is the possible movie, sampled and resized with PIL
        movie = dataset_root / "dev" / pair["possible"]
        expected = np.asarray(
            Image.fromarray(read_png(movie / "scene" / f"scene_{SAMPLED[2] + 1:03d}.png")).resize(
                (16, 16), Image.Resampling.BILINEAR
            )
        )
        assert np.array_equal(con[2].numpy(), expected)
    assert [dm.variant_names[int(r["variant"])] for r in records[:2]] == [
        "standard",
        "counterbalanced",
    ]
    assert [entry["condition"] for entry in table.values()] == [
        "visible_static",
        "occluded_dynamic_1",
        "unspecified",
    ]
    assert dm.probe_cases() == [
        ("O1_object_permanence", "standard"),
        ("O1_object_permanence", "counterbalanced"),
        ("O2_shape_constancy", "standard"),
        ("O2_shape_constancy", "counterbalanced"),
    ]
    assert dm.skipped == {}


def fake_outputs(dm, surprise_of_movie):
    """probe_step-like outputs whose per-frame surprise sums to the given movie totals."""
    records = torch.cat(list(dm.test_dataloader()))
    table = dm.quadruplets("dev")
    pairs = [table[int(s)]["pairs"][int(v)] for s, v in zip(records["seed"], records["variant"])]

    def frames_of(totals):
        return torch.tensor(totals, dtype=torch.float64)[:, None].expand(-1, 5) / 5

    return {
        "concept": records["concept"],
        "variant": records["variant"],
        "seed": records["seed"],
        "manipulation_frame": records["manipulation_frame"],
        "surprise_consistent": frames_of([surprise_of_movie[p["possible"]] for p in pairs]),
        "surprise_inconsistent": frames_of([surprise_of_movie[p["impossible"]] for p in pairs]),
    }


def test_benchmark_metrics_per_block_match_hand_computed_values(dataset_root):
    dm = datamodule(dataset_root)
    dm.setup("test")
    s1, s2, s3 = SCENES
    f1, f2, f3 = (SCENES[s][2] for s in SCENES)
    surprise = {
        # scene 1: possible 1 + 2 = 3 < impossible 3 + 4 = 7 (correct)
        f"{s1}/{f1[0]}": 1.0,
        f"{s1}/{f1[1]}": 2.0,
        f"{s1}/{f1[2]}": 3.0,
        f"{s1}/{f1[3]}": 4.0,
        # scene 2: possible 5 + 1 = 6 > impossible 2 + 3 = 5 (error)
        f"{s2}/{f2[0]}": 5.0,
        f"{s2}/{f2[1]}": 1.0,
        f"{s2}/{f2[2]}": 2.0,
        f"{s2}/{f2[3]}": 3.0,
        # scene 3 (O2): a tie, no error (half an error with ties half)
        f"{s3}/{f3[0]}": 2.0,
        f"{s3}/{f3[1]}": 2.0,
        f"{s3}/{f3[2]}": 1.0,
        f"{s3}/{f3[3]}": 3.0,
    }
    report = external_metrics(
        dm.external_pairs(), fake_outputs(dm, surprise), bootstrap=0, alpha=ALPHA
    )
    o1 = report["metrics"]["O1_object_permanence"]
    assert o1["all"]["relative_error_rate"] == pytest.approx(0.5)
    # impossible {3, 4, 2, 3} vs possible {1, 2, 5, 1}: 11.5 of 16 pairs ranked right
    assert o1["all"]["auroc"] == pytest.approx(11.5 / 16)
    assert o1["all"]["absolute_error_rate"] == pytest.approx(4.5 / 16)
    assert (
        o1["visible"]["relative_error_rate"] == 0.0 and o1["occluded"]["relative_error_rate"] == 1.0
    )
    assert o1["all"]["paired_test"]["n"] == 4
    o2 = report["metrics"]["O2_shape_constancy"]["all"]
    assert o2["relative_error_rate"] == 0.0 and o2["relative_error_rate_ties_half"] == 0.5
    assert o2["auroc"] == pytest.approx(0.5)  # impossible {1, 3} vs possible {2, 2}
    assert report["incomplete_quadruplets"] == 0 and report["skipped"] == {}


class MeanIntensityModel(SurpriseModel):
    """Stands in for VRNNLRUModel: per-frame 'surprise' = mean pixel intensity."""

    def surprise(self, frames, mask=None, camera=None):
        return frames.float().mean(dim=(-1, -2, -3))

    def expected_frames(self, frames, mask=None, camera=None):
        return specs.to_model_input(frames)

    def trajectories(self, frames, mask=None, camera=None):
        return {}


def predict(dm, path):
    """``predict`` of ``dm``'s predict split with the answer writer at ``path``: movie path ->
    total surprise, as predict_step returned it."""
    trainer = L.Trainer(
        accelerator="cpu",
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[IntPhysAnswerWriter(path)],
    )
    batches = trainer.predict(MeanIntensityModel(), datamodule=dm)
    movies = dm.movies(dm.hparams.predict_split)
    return {
        movies[index].name: value
        for batch in batches
        for index, value in zip(batch["index"].tolist(), batch["surprise"].tolist())
    }


def test_answer_file_for_the_unlabelled_test_set(dataset_root, tmp_path):
    dm = datamodule(dataset_root)
    dm.setup("predict")
    batch = next(iter(dm.predict_dataloader()))
    assert batch["frames"].shape == (4, 5, 16, 16, 3)
    path = tmp_path / "answer.txt"
    scores = predict(dm, path)
    lines = path.read_text().splitlines()
    assert len(lines) == 12 and lines == sorted(lines)
    assert all(re.fullmatch(r"O[12]/[^ /]+/[1-4] \S+", line) for line in lines)
    assert all(0 <= float(line.split()[1]) <= 1 for line in lines)
    assert lines[0].startswith("O1/0001_O1_test_visible_static_nobj1/1 ")
    answers = read_answer_file(path)
    assert set(answers) == set(scores)
    lowest, highest = min(scores, key=scores.get), max(scores, key=scores.get)
    assert answers[lowest] == 1.0 and answers[highest] == 0.0


def test_answer_file_scores_equal_the_surprise_metrics_on_dev(dataset_root, tmp_path):
    dm = datamodule(dataset_root, predict_split="dev")
    surprise = predict(dm, tmp_path / "answer.txt")
    from_surprise = external_metrics(
        dm.external_pairs(), fake_outputs(dm, surprise), bootstrap=0, alpha=ALPHA
    )["metrics"]
    answers = read_answer_file(tmp_path / "answer.txt")
    labels = {m.name: m.is_possible for m in dm.movies("dev")}
    official = score_answers(answers, labels)
    for block, concept in [("O1", "O1_object_permanence"), ("O2", "O2_shape_constancy")]:
        for condition, values in official[block].items():
            for metric in values:
                assert values[metric] == pytest.approx(from_surprise[concept][condition][metric])


@pytest.mark.slow
def test_predict_under_ddp_scores_each_movie_once_and_writes_the_same_answer(
    dataset_root, tmp_path
):
    """Two CPU processes (ddp_spawn over gloo) split the movies unevenly in batches (6 each,
    batches of 5 + 1); the writer gathers them into the answer one process writes."""
    predict(datamodule(dataset_root), tmp_path / "single.txt")
    trainer = L.Trainer(
        accelerator="cpu",
        devices=2,
        strategy="ddp_spawn",
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[IntPhysAnswerWriter(tmp_path / "ddp.txt")],
    )
    trainer.predict(
        MeanIntensityModel(),
        datamodule=datamodule(dataset_root, probe_batch_size=5),
        return_predictions=False,
    )
    assert (tmp_path / "ddp.txt").read_text() == (tmp_path / "single.txt").read_text()


def test_training_movies_become_clips(dataset_root):
    dm = datamodule(dataset_root)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["frames"].shape == (2, 5, 16, 16, 3)
    for record in batch:
        assert dm.clip_spec().is_in(record)
    assert dm.concept_names[int(batch["concept"][0])] == "train"


def test_cache_is_reused_without_decoding_pngs(dataset_root, tmp_path, monkeypatch):
    first = datamodule(dataset_root, cache_dir=str(tmp_path / "cache"))
    first.setup("fit")
    expected_probes = torch.cat(list(first.test_dataloader()))
    expected_clips = torch.stack([first._train[i] for i in range(len(first._train))])

    def refuse(path):
        raise AssertionError(f"decoded {path} although the cache is complete")

    monkeypatch.setattr(intphys, "read_png", refuse)
    second = datamodule(dataset_root, cache_dir=str(tmp_path / "cache"))
    second.setup("fit")
    probes = torch.cat(list(second.test_dataloader()))
    assert (probes == expected_probes).all()
    assert second.quadruplets("dev") == first.quadruplets("dev")
    clips = torch.stack([second._train[i] for i in range(len(second._train))])
    assert (clips == expected_clips).all()


def cache_manifest_not_json(folder):
    (folder / "manifest.json").write_text('{"format": "voe_lightning.store/1", "shar')
    return rf"{re.escape(str(folder / 'manifest.json'))}: unreadable JSON"


def cache_manifest_of_wrong_shape(folder):
    meta = json.loads((folder / "manifest.json").read_text())
    meta["shard_size"] = "6"
    (folder / "manifest.json").write_text(json.dumps(meta))
    return rf"{re.escape(str(folder / 'manifest.json'))}: shard_size is a str"


def cache_manifest_without_the_table(folder):
    meta = json.loads((folder / "manifest.json").read_text())
    del meta["table"]
    (folder / "manifest.json").write_text(json.dumps(meta))
    return rf"{re.escape(str(folder / 'manifest.json'))}: table is missing"


def cache_shard(folder):
    return folder / "benchmark" / "records" / "shard-00000.voe"


def cache_shard_with_a_flipped_byte(folder):
    shard = cache_shard(folder)
    data = bytearray(shard.read_bytes())
    data[20] ^= 0xFF  # inside the first record
    shard.write_bytes(bytes(data))
    return rf"{re.escape(str(shard))}: record 0 checksum mismatch"


def cache_shard_missing(folder):
    cache_shard(folder).unlink()
    return rf"{re.escape(str(cache_shard(folder)))}: missing"


@pytest.mark.parametrize(
    "breakage",
    [
        cache_manifest_not_json,
        cache_manifest_of_wrong_shape,
        cache_manifest_without_the_table,
        cache_shard_with_a_flipped_byte,
        cache_shard_missing,
    ],
)
def test_a_bad_cache_warns_naming_it_and_is_rebuilt_from_the_source(
    dataset_root, tmp_path, breakage
):
    """Issue 10 case 8: a bad cache is no cache; it is rebuilt, not blamed on generate."""
    cache = str(tmp_path / "cache")
    first = datamodule(dataset_root, cache_dir=cache)
    expected = torch.cat(list(first.test_dataloader()))
    (folder,) = (tmp_path / "cache" / "intphys" / "dev").iterdir()
    where = breakage(folder)
    second = datamodule(dataset_root, cache_dir=cache)
    with pytest.warns(UserWarning, match=rf"bad benchmark cache {where}.*rebuilding it") as caught:
        probes = torch.cat(list(second.test_dataloader()))
    assert not any("generate" in str(w.message) for w in caught)
    assert (probes == expected).all()
    assert second.quadruplets("dev") == first.quadruplets("dev")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the rebuilt cache is intact
        assert len(datamodule(dataset_root, cache_dir=cache).probes("dev")) == 6


def test_a_cache_shard_that_goes_bad_in_use_names_the_cache_and_the_fix(dataset_root, tmp_path):
    probes = datamodule(dataset_root, cache_dir=str(tmp_path / "cache")).probes("dev")
    (folder,) = (tmp_path / "cache" / "intphys" / "dev").iterdir()
    cache_shard_with_a_flipped_byte(folder)
    message = rf"benchmark cache {re.escape(str(folder))}.*rebuilds it"
    with pytest.raises(OSError, match=message) as error:
        probes[0]
    assert "generate" not in str(error.value)


def break_missing_frame(root):
    (root / "dev" / "O1/0002_O1_test_occluded_dynamic_1_nobj2/3/scene/scene_007.png").unlink()
    return (
        r"missing frame .*0002_O1_test_occluded_dynamic_1_nobj2/3/scene/scene_007\.png.*scene_020\.png",
        "missing_frame",
    )


def break_movie_count(root):
    shutil.rmtree(root / "dev" / "O2/0003/4")
    return (
        r"scene .*O2/0003 holds movies \['1', '2', '3'\]; expected exactly the 4 movies",
        "wrong_movie_count",
    )


def break_png(root):
    (root / "dev" / "O1/0001_O1_test_visible_static_nobj1/2/scene/scene_011.png").write_bytes(
        b"\x89PNG broken"
    )
    return (
        r"unreadable PNG .*0001_O1_test_visible_static_nobj1/2/scene/scene_011\.png",
        "unreadable_png",
    )


def break_png_bomb(root):
    """Issue 10 case 7: a PNG whose header claims 30000x30000 pixels, past PIL's bomb limit."""
    path = root / "dev" / "O1/0001_O1_test_visible_static_nobj1/2/scene/scene_011.png"
    data = bytearray(path.read_bytes())
    ihdr = 8 + 8  # after the signature, the IHDR chunk's length and type
    data[ihdr : ihdr + 8] = struct.pack(">II", 30000, 30000)
    data[ihdr + 13 : ihdr + 17] = struct.pack(">I", zlib.crc32(bytes(data[ihdr - 4 : ihdr + 13])))
    path.write_bytes(bytes(data))
    return (
        r"unreadable PNG .*0001_O1_test_visible_static_nobj1/2/scene/scene_011\.png: its header "
        r"claims a frame too large to decode safely \(Image size \(900000000 pixels\)",
        "unreadable_png",
    )


def break_label(root):
    (root / "dev" / "O2/0003/1/status.json").unlink()
    return r"missing .*O2/0003/1/status\.json: .*header\.is_possible", "missing_label"


def break_label_count(root):
    path = root / "dev" / "O1/0001_O1_test_visible_static_nobj1/3/status.json"
    path.write_text(json.dumps({"header": {"is_possible": True}}))
    return (
        r"0001_O1_test_visible_static_nobj1 has 3 possible and 1 impossible movies.*expected 2 and 2",
        "wrong_label_count",
    )


@pytest.mark.parametrize(
    "breakage",
    [
        break_missing_frame,
        break_movie_count,
        break_png,
        break_png_bomb,
        break_label,
        break_label_count,
    ],
)
def test_bad_input_raises_naming_the_file_or_is_skipped_and_counted_when_lenient(
    dataset_root, tmp_path, breakage
):
    root = fresh_copy(dataset_root, tmp_path)
    message, reason = breakage(root)
    with pytest.raises(BenchmarkDataError, match=message):
        datamodule(root).setup("test")
    lenient = datamodule(root, lenient=True)
    lenient.setup("test")
    assert len(lenient.probes("dev")) == 4  # the two intact scenes
    assert lenient.skipped == {reason: 1}
    outputs = {
        "seed": torch.cat(list(lenient.test_dataloader()))["seed"],
        "surprise_consistent": torch.zeros(4, 5),
        "surprise_inconsistent": torch.ones(4, 5),
    }
    metrics = external_metrics(lenient.external_pairs(), outputs, bootstrap=0, alpha=ALPHA)
    assert metrics["skipped"] == {reason: 1}


def test_lenient_loading_writes_nothing_to_the_temp_directory(dataset_root, tmp_path, monkeypatch):
    """Issue 10 case 12: skips are counted without voe_skipped_<uuid> folders in the temp dir."""
    root = fresh_copy(dataset_root, tmp_path)
    break_png(root)
    shutil.rmtree(root / "train" / "00001" / "scene")
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    dm = datamodule(root, lenient=True)
    dm.setup("fit")
    assert len(dm.probes("dev")) == 4
    assert dm.skipped == {"missing_frame": 1, "unreadable_png": 1}
    assert list(scratch.iterdir()) == []


def test_pairs_that_never_differ_in_the_sampled_frames_are_refused(dataset_root, tmp_path):
    root = fresh_copy(dataset_root, tmp_path)
    # scene 2's B->A switch happens at frame 16: sampling only frames 0..12 never sees it
    with pytest.raises(
        BenchmarkDataError, match=r"do not differ in any of the 4 sampled frames \[0, 4, 8, 12\]"
    ):
        datamodule(root, num_frames=4, frame_stride=4).setup("test")


def test_missing_split_and_bad_arguments_name_the_valid_choices(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"no IntPhys dev set at .*dev; expected"):
        datamodule(tmp_path).setup("test")
    with pytest.raises(ValueError, match="eval_split must be 'dev' or 'test'"):
        datamodule(tmp_path, eval_split="train")
    with pytest.raises(ValueError, match="need frame 24, but movies have 20 frames"):
        datamodule(tmp_path, num_frames=5, frame_stride=6)


def test_a_report_tests_each_block_over_its_scenes_quadruplets(dataset_root):
    """Issue 48 part 2: both pairs of a scene carry its quadruplet index as seed and their half
    as variant, so the report tests each block over its scenes (``statistics.quadruplet_test``,
    IntPhys' unit) and reads the block's verdict from that row."""
    dm = datamodule(dataset_root)
    dm.setup("test")
    probes = torch.cat(list(dm.test_dataloader()))
    check_quadruplet_rows(
        probes,
        dm.concept_names,
        dm.variant_names,
        {"O1_object_permanence": 2, "O2_shape_constancy": 1},
    )
