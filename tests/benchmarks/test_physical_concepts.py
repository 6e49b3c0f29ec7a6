"""DeepMind Physical Concepts reader on GZIP TFRecord shards written with the tfrecord
package in the released feature layout: CRC checks, decoding, pairing by divergence, the
DataModule's loaders and metrics, the cache, and every bad-input error."""

import gc
import gzip
import tempfile

import pytest
import torch
from helpers import ALPHA
from helpers.physical_concepts import (
    CONCEPTS,
    SAMPLED,
    SWITCHES,
    datamodule,
    freeform_example,
    make_dataset,
    probe_example,
    write_shard,
)
from helpers.quadruplets import check_quadruplet_rows

import voe_lightning.benchmarks.physical_concepts.reader as physical_concepts
from voe_lightning.benchmarks.evaluation import external_metrics
from voe_lightning.benchmarks.physical_concepts.reader import read_records
from voe_lightning.benchmarks.reader import BenchmarkDataError


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("physical_concepts"))


def first_sampled_at_or_after(frame: int) -> int:
    return next(k for k, source in enumerate(SAMPLED) if source >= frame)


def test_records_are_read_with_both_checksums_verified(tmp_path):
    path = tmp_path / "data.tfrecord-00000-of-00001"
    write_shard(path, [freeform_example(k) for k in range(3)])
    assert len(list(read_records(path))) == 3
    write_shard(path, [freeform_example(k) for k in range(3)], corrupt_record=1)
    with pytest.raises(
        BenchmarkDataError,
        match=r"data\.tfrecord-00000-of-00001: record 1: payload checksum mismatch",
    ):
        list(read_records(path))
    skipped = []
    assert len(list(read_records(path, skip=skipped.append))) == 2
    assert [e.reason for e in skipped] == ["bad_crc"]
    write_shard(path, [freeform_example(k) for k in range(3)], truncate=-200)
    with pytest.raises(BenchmarkDataError, match=r"data\.tfrecord-00000-of-00001: truncated"):
        list(read_records(path))


def test_freeform_training_clips_stream_with_spec_shapes(dataset_root):
    dm = datamodule(dataset_root)
    dm.setup("fit")
    clips = torch.cat(list(dm.train_dataloader()))
    assert clips.batch_size == torch.Size([6])  # 2 shards x 3 records, batches of 2
    assert sorted(clips["seed"].tolist()) == [0, 1, 2, 1_000_000, 1_000_001, 1_000_002]
    for clip in clips:
        assert dm.clip_spec().is_in(clip)
        assert dm.concept_names[int(clip["concept"])] == "freeform"
    assert clips["frames"].shape == (6, 5, 32, 32, 3) and clips["mask"].shape == (6, 5, 32, 32)
    seed = int(clips["seed"][0])
    source = 10 * (seed // 1_000_000) + seed % 1_000_000
    assert clips["camera"][0, :, 0].tolist() == [source + t for t in SAMPLED]
    assert set(clips["mask"].unique().tolist()) == {0, 1}  # nearest resizing keeps ids


def test_probe_quadruplets_become_pairs_recovered_from_divergence(dataset_root):
    dm = datamodule(dataset_root)
    dm.setup("test")
    probes = torch.cat(list(dm.test_dataloader()))
    assert probes.batch_size == torch.Size([16])  # 2 concepts x 2 shards x 2 records x 2 pairs
    assert probes["consistent", "frames"].shape == (16, 5, 32, 32, 3)
    for probe in probes:
        assert dm.probe_spec().is_in(probe)
        record = int(probe["seed"]) % 1_000_000
        pair = int(probe["variant"])  # the quadruplet's half: 0 standard, 1 counterbalanced
        switch_ab, switch_ba = SWITCHES[record]
        # pair 0: possible A with impossible A->B; pair 1: possible B with impossible B->A
        expected = first_sampled_at_or_after(switch_ab if pair == 0 else switch_ba)
        m = int(probe["manipulation_frame"])
        assert m == expected
        con, inc = probe["consistent", "frames"], probe["inconsistent", "frames"]
        assert torch.equal(con[:m], inc[:m]) and not torch.equal(con[m], inc[m])
        assert probe["camera"][:, 0].tolist() == [100 * pair + t for t in SAMPLED]
        assert set(probe["consistent", "mask"].unique().tolist()) == {0, 1 + pair}
    assert [dm.concept_names[c] for c in probes["concept"].unique().tolist()] == CONCEPTS
    assert dm.probe_cases() == [
        ("continuity", "standard"),
        ("continuity", "counterbalanced"),
        ("solidity", "standard"),
        ("solidity", "counterbalanced"),
    ]
    validation = torch.cat(list(dm.val_dataloader()))
    assert validation.batch_size == torch.Size([4])  # 1 quadruplet per concept


def test_benchmark_metrics_per_concept_from_probe_outputs(dataset_root):
    dm = datamodule(dataset_root)
    dm.setup("test")
    probes = torch.cat(list(dm.test_dataloader()))
    solidity = probes["concept"] == 1
    # continuity: impossible always more surprising; solidity: possible more surprising
    impossible = torch.where(solidity, 1.0, 3.0)[:, None].expand(-1, 5)
    outputs = {
        "concept": probes["concept"],
        "seed": probes["seed"],
        "surprise_consistent": torch.full((16, 5), 2.0),
        "surprise_inconsistent": impossible,
    }
    metrics = external_metrics(dm.external_pairs(), outputs, bootstrap=0, alpha=ALPHA)
    assert metrics["metrics"]["continuity"]["all"]["relative_error_rate"] == 0.0
    assert metrics["metrics"]["continuity"]["all"]["auroc"] == 1.0
    assert metrics["metrics"]["continuity"]["all"]["n_quadruplets"] == 4
    assert metrics["metrics"]["solidity"]["all"]["relative_error_rate"] == 1.0
    assert metrics["metrics"]["solidity"]["all"]["absolute_error_rate"] == 1.0
    assert metrics["incomplete_quadruplets"] == 0 and metrics["skipped"] == {}


def test_cache_serves_the_same_records_without_reading_tfrecords(
    dataset_root, tmp_path, monkeypatch
):
    first = datamodule(dataset_root, cache_dir=str(tmp_path / "cache"))
    first.setup("fit")
    first.setup("test")
    expected = torch.cat(list(first.test_dataloader()))
    streamed = torch.cat(list(datamodule(dataset_root).test_dataloader()))
    assert (expected == streamed).all()

    def refuse(*args, **kwargs):
        raise AssertionError("read a TFRecord although the cache is complete")

    monkeypatch.setattr(physical_concepts, "read_records", refuse)
    second = datamodule(dataset_root, cache_dir=str(tmp_path / "cache"))
    second.setup("fit")
    second.setup("test")
    assert (torch.cat(list(second.test_dataloader())) == expected).all()
    clips = torch.cat(list(second.train_dataloader()))
    assert sorted(clips["seed"].tolist()) == [0, 1, 2, 1_000_000, 1_000_001, 1_000_002]
    assert torch.cat(list(second.val_dataloader())).batch_size == torch.Size([4])


def test_cached_validation_takes_whole_quadruplets_of_the_first_shard(dataset_root, tmp_path):
    """Issue 10 case 16: two workers write shard 0's and shard 1's probe pairs interleaved into
    the cache; validation still takes the first quadruplets of the first shard, both pairs of
    each, as streaming does."""
    options = dict(concepts=["continuity"], val_quadruplets_per_concept=1)
    dm = datamodule(dataset_root, cache_dir=str(tmp_path / "cache"), num_workers=2, **options)
    dm.setup("validate")
    cached = dm._dataset("probes/continuity")
    # seed = quadruplet_index = shard * 1_000_000 + record; its pairs, the variants 0 and 1
    assert [int(cached[i]["seed"]) for i in range(2)] == [0, 1_000_000]
    validation = dm._validation_set("continuity")
    seeds = sorted(int(validation[i]["seed"]) for i in range(len(validation)))
    assert seeds == [0, 0]
    assert sorted(int(validation[i]["variant"]) for i in range(len(validation))) == [0, 1]
    streamed = torch.cat(list(datamodule(dataset_root, **options).val_dataloader()))["seed"]
    assert sorted(streamed.tolist()) == seeds


def corrupt_crc(root):
    path = root / "probes" / "solidity" / "data.tfrecord-00001-of-00002"
    write_shard(path, [probe_example(20 + k, *SWITCHES[k]) for k in range(2)], corrupt_record=0)
    return (
        r"solidity/data\.tfrecord-00001-of-00002: record 0: payload checksum mismatch",
        "bad_crc",
        14,
    )


def truncate_shard(root):
    path = root / "probes" / "continuity" / "data.tfrecord-00000-of-00002"
    write_shard(path, [probe_example(k, *SWITCHES[k]) for k in range(2)], truncate=-5000)
    return r"continuity/data\.tfrecord-00000-of-00002: truncated", "truncated", 14


def wrong_byte_count(root):
    example = probe_example(20, *SWITCHES[0])
    example["possible_image"] = (example["possible_image"][0][:-64], "byte")
    path = root / "probes" / "continuity" / "data.tfrecord-00001-of-00002"
    write_shard(path, [example, probe_example(21, *SWITCHES[1])])
    return (
        r"continuity/data\.tfrecord-00001-of-00002, record 0: feature 'possible_image' holds 368576 "
        r"bytes, expected 368640 bytes \(uint8 \[2, 15, 64, 64, 3\]\)",
        "wrong_byte_count",
        14,
    )


def missing_shard(root):
    (root / "probes" / "solidity" / "data.tfrecord-00000-of-00002").unlink()
    return (
        r"missing shard .*solidity/data\.tfrecord-00000-of-00002; expected 2 shards",
        "missing_shard",
        12,
    )


@pytest.mark.parametrize("breakage", [corrupt_crc, truncate_shard, wrong_byte_count, missing_shard])
def test_bad_input_raises_naming_the_file_or_is_skipped_and_counted_when_lenient(
    dataset_root, tmp_path, breakage
):
    import shutil

    root = tmp_path / "data"
    shutil.copytree(dataset_root, root)
    message, reason, remaining = breakage(root)
    with pytest.raises(BenchmarkDataError, match=message):
        dm = datamodule(root)
        dm.setup("test")
        list(dm.test_dataloader())
    lenient = datamodule(root, lenient=True)
    lenient.setup("test")
    assert len(torch.cat(list(lenient.test_dataloader()))) == remaining
    assert lenient.skipped == {reason: 1}


def test_skips_in_worker_processes_are_counted_once_without_temp_files(
    dataset_root, tmp_path, monkeypatch
):
    """Issue 10 case 12: two spawned DataLoader workers report their skips to the DataModule
    without writing to the temp directory; a record skipped again next epoch counts once."""
    import shutil

    root = tmp_path / "data"
    shutil.copytree(dataset_root, root)
    corrupt_crc(root)
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    monkeypatch.setenv("TMPDIR", str(scratch))  # the workers' temp directory too
    dm = datamodule(root, lenient=True, num_workers=2)
    dm.setup("test")
    loader = dm.test_dataloader()
    for _ in range(2):
        assert len(torch.cat(list(loader))) == 14
    assert dm.skipped == {"bad_crc": 1}
    del loader  # its workers exit, removing the pymp-* folders multiprocessing made there
    gc.collect()
    assert list(scratch.iterdir()) == []


def test_lenient_counts_survive_in_the_cache(dataset_root, tmp_path):
    import shutil

    root = tmp_path / "data"
    shutil.copytree(dataset_root, root)
    corrupt_crc(root)
    for _ in range(2):  # build, then reuse
        dm = datamodule(root, lenient=True, cache_dir=str(tmp_path / "cache"))
        dm.setup("test")
        assert len(torch.cat(list(dm.test_dataloader()))) == 14
        assert dm.skipped == {"bad_crc": 1}


def test_bad_arguments_name_the_valid_choices(tmp_path):
    with pytest.raises(ValueError, match="valid concepts are: continuity, solidity"):
        datamodule(tmp_path, concepts=["gravity"])
    with pytest.raises(ValueError, match="cannot take 20 frames from movies of 15 frames"):
        datamodule(tmp_path, num_frames=20)
    with pytest.raises(FileNotFoundError, match="no folder .*probes/continuity"):
        datamodule(tmp_path).setup("test")


@pytest.mark.parametrize(
    "content", [b"", gzip.compress(b"")], ids=["zero_bytes", "gzip_of_nothing"]
)
def test_an_empty_shard_is_an_error_or_a_counted_skip(tmp_path, content):
    """Issue 10 case 6: an empty file is not a shard of zero records."""
    path = tmp_path / "data.tfrecord-00000-of-00001"
    path.write_bytes(content)
    with pytest.raises(
        BenchmarkDataError, match=rf"{path}: empty \({len(content)} bytes, no records\)"
    ):
        list(read_records(path))
    skipped = []
    assert list(read_records(path, skip=skipped.append)) == []
    assert [error.reason for error in skipped] == ["empty"]


def test_a_report_tests_each_concept_over_its_quadruplets(dataset_root):
    """Issue 48 part 2: a record's seed names its quadruplet and its variant the half, as in
    our stores, so the report's quadruplet row (D = [S(AB) - S(A)] + [S(BA) - S(B)] per
    quadruplet) and the quadruplet verdict apply to it."""
    dm = datamodule(dataset_root)
    dm.setup("test")
    probes = torch.cat(list(dm.test_dataloader()))
    check_quadruplet_rows(
        probes, dm.concept_names, dm.variant_names, {concept: 4 for concept in CONCEPTS}
    )  # 2 shards x 2 records
