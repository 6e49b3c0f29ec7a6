"""The record store: lossless round trip of clips and probes, random access from DataLoader
workers, compression of structured videos, and corrupt or truncated shards named on read."""

import os
import pickle
import stat

import pytest
import torch
from helpers.stores import fake_clip, fake_probe
from tensordict import TensorDict
from torch.utils.data import DataLoader

from voe_lightning import scenes, specs
from voe_lightning.benchmarks.cache import write_cache
from voe_lightning.data import store
from voe_lightning.data.store import files, render


def _equal(a: TensorDict, b: TensorDict) -> bool:
    keys = sorted(a.keys(True, True), key=str)
    return keys == sorted(b.keys(True, True), key=str) and all(
        a[k].dtype == b[k].dtype and torch.equal(a[k], b[k]) for k in keys
    )


def test_round_trip_is_lossless_for_random_clips_and_probes(tmp_path):
    torch.manual_seed(0)
    clips = [specs.clip_spec(5, 12, 10).rand() for _ in range(4)]  # odd sizes, random bytes
    probes = [specs.probe_spec().rand() for _ in range(3)]
    store.write_shard(tmp_path / "clips.voe", clips)
    store.write_shard(tmp_path / "probes.voe", probes, {"note": "kept"})
    clip_reader, probe_reader = (
        store.ShardReader(tmp_path / "clips.voe"),
        store.ShardReader(tmp_path / "probes.voe"),
    )
    assert len(clip_reader) == 4 and len(probe_reader) == 3
    for i in (2, 0, 3, 1):  # random order
        assert _equal(clip_reader[i], clips[i])
        assert specs.clip_spec(5, 12, 10).is_in(clip_reader[i])
    for i in range(3):
        assert _equal(probe_reader[i], probes[i]) and specs.probe_spec().is_in(probe_reader[i])
    assert probe_reader.index.meta["note"] == "kept"
    assert probe_reader.index.seeds == [int(p["seed"]) for p in probes]
    with pytest.raises(IndexError, match="out of range"):
        clip_reader[4]


def test_generated_records_round_trip_exactly_with_their_object_states(tmp_path):
    """Rendered records, nested float and int object states beside the uint8 videos, come back
    bit for bit."""
    records = {
        "clip": scenes.generate_clip("containment", "example", 0),
        "probe": scenes.generate_probe("unchangeableness", "shape", 0),
    }
    for name, record in records.items():
        store.write_shard(tmp_path / f"{name}.voe", [record])
        stored = store.ShardReader(tmp_path / f"{name}.voe")[0]
        assert _equal(stored, record)
        objects = stored["objects"] if name == "clip" else stored["inconsistent", "objects"]
        assert objects["position"].dtype == torch.float32
        assert objects["shape_label"].dtype == torch.int64 and objects["shape_label"].any()


def test_structured_videos_compress_well_below_40_kb(tmp_path):
    clips = [fake_clip("solidity", "example", seed) for seed in range(8)]
    probes = [fake_probe("solidity", "standard", seed) for seed in range(8)]
    clip_bytes = store.write_shard(tmp_path / "c.voe", clips)
    probe_bytes = store.write_shard(tmp_path / "p.voe", probes)
    raw = 15 * 64 * 64 * 4  # frames and mask of one video
    assert clip_bytes / 8 < raw / 10
    # The inconsistent video is stored as its difference from the consistent one.
    assert probe_bytes / 16 < clip_bytes / 8


def _split_root(tmp_path, count=10, shard_size=4, concept="continuity"):
    manifest = {
        "shard_size": shard_size,
        "video": {"num_frames": 15, "height": 64, "width": 64},
        "concepts": {
            concept: {
                "splits": {
                    s: {"record_type": store.SPLIT_RECORD_TYPE[s], "count": 0} for s in store.SPLITS
                }
            }
        },
    }
    manifest["concepts"][concept]["splits"]["train"]["count"] = count
    clips = [fake_clip(concept, "example", seed) for seed in range(count)]
    for index, start in enumerate(range(0, count, shard_size)):
        store.write_shard(
            store.shard_path(tmp_path, concept, "train", index), clips[start : start + shard_size]
        )
    store.write_manifest(tmp_path, manifest)
    return clips


def test_open_split_reads_every_record_from_dataloader_workers(tmp_path):
    clips = _split_root(tmp_path)
    dataset = store.open_split(tmp_path, "continuity", "train")
    assert len(dataset) == 10 and dataset.spec.is_in(dataset[-1])
    assert _equal(dataset[5], clips[5])
    # fork keeps the test fast (torchrl makes spawn the default); spawn pickles the dataset
    # after use, which must drop the open files and reopen them in the worker.
    clone = pickle.loads(pickle.dumps(dataset))
    assert clone._readers == {} and _equal(clone[9], clips[9])
    loader = DataLoader(
        dataset,
        batch_size=3,
        num_workers=2,
        collate_fn=store.collate,
        multiprocessing_context="fork",
    )
    batches = list(loader)
    assert batches[0].batch_size == torch.Size([3])
    seeds = torch.cat([batch["seed"] for batch in batches]).tolist()
    assert seeds == list(range(10))
    assert torch.equal(
        torch.cat([b["frames"] for b in batches]), torch.stack([c["frames"] for c in clips])
    )
    assert len(store.open_split(tmp_path, "continuity", "generalization")) == 0


def test_corrupt_and_truncated_shards_are_named(tmp_path, monkeypatch):
    monkeypatch.setattr(render, "generate_clip", fake_clip)
    store.generate_dataset(
        tmp_path, ("continuity",), train_examples=5, val_pairs=0, test_pairs=0,
        generalization_pairs=0, shard_size=4, workers=1, progress=False,
    )  # fmt: skip
    assert store.verify(tmp_path) == []
    fifth = store.open_split(tmp_path, "continuity", "train")[5]
    corrupt = store.shard_path(tmp_path, "continuity", "train", 1)
    data = bytearray(corrupt.read_bytes())
    data[100] ^= 0xFF  # inside the first record's blob
    corrupt.write_bytes(bytes(data))
    truncated = store.shard_path(tmp_path, "continuity", "train", 2)
    truncated.write_bytes(truncated.read_bytes()[:-10])
    dataset = store.open_split(tmp_path, "continuity", "train")
    with pytest.raises(store.CorruptShardError, match=str(corrupt)):
        dataset[4]
    with pytest.raises(store.CorruptShardError, match=str(truncated)):
        dataset[8]
    assert _equal(dataset[5], fifth)  # other records still readable
    assert store.verify(tmp_path) == [corrupt, truncated]
    store.shard_path(tmp_path, "continuity", "train", 0).unlink()
    assert store.verify(tmp_path)[0] == store.shard_path(tmp_path, "continuity", "train", 0)


def test_failed_write_names_the_path_and_leaves_no_temporary(tmp_path, monkeypatch):
    def full_disk(file, data):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(files, "_write_bytes", full_disk)
    path = tmp_path / "concept" / "train" / "shard-00000.voe"
    with pytest.raises(OSError, match=str(path)) as error:
        store.write_shard(path, [fake_clip("solidity", "example", 0)])
    assert error.value.errno == 28
    assert list(path.parent.iterdir()) == []


def test_open_split_rejects_bad_names(tmp_path):
    _split_root(tmp_path)
    with pytest.raises(
        ValueError, match="valid concepts are: object_persistence, unchangeableness"
    ):
        store.open_split(tmp_path, "gravity", "train")
    with pytest.raises(ValueError, match="valid splits are: train, val, test, generalization"):
        store.open_split(tmp_path, "continuity", "training")
    with pytest.raises(ValueError, match="not generated .* holds: continuity"):
        store.open_split(tmp_path, "solidity", "train")
    with pytest.raises(FileNotFoundError, match="manifest.json"):
        store.open_split(tmp_path / "nothing", "solidity", "train")
    manifest = store.read_manifest(tmp_path)
    manifest["vocabulary"] = {**store.vocabulary(), "variants": ["standard"]}
    store.write_manifest(tmp_path, manifest)
    with pytest.raises(ValueError, match="other concept/kind/variant names"):
        store.open_split(tmp_path, "continuity", "train")


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o027, 0o640), (0o002, 0o664)])
def test_written_files_respect_the_umask(tmp_path, umask, mode):
    """Issue 10 case 3: a dataset made for a lab is readable as the umask allows, not 0600."""
    previous = os.umask(umask)
    try:
        store.write_shard(tmp_path / "a.voe", [fake_clip("continuity", "example", 0)])
        store.write_manifest(tmp_path, {"format": store.FORMAT})
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / "a.voe").stat().st_mode) == mode
    assert stat.S_IMODE((tmp_path / "manifest.json").stat().st_mode) == mode


@pytest.mark.parametrize("umask, mode", [(0o022, 0o755), (0o027, 0o750)])
def test_a_benchmark_cache_folder_respects_the_umask(tmp_path, umask, mode):
    """The cache is staged in a mkdtemp folder (always 0700) and renamed into place: a lab's
    shared cache must open for others as the umask allows."""
    previous = os.umask(umask)
    try:
        cache = write_cache(
            tmp_path / "cache", [fake_clip("continuity", "example", 0)], specs.clip_spec()
        )
    finally:
        os.umask(previous)
    assert stat.S_IMODE(cache.root.stat().st_mode) == mode
    assert all(
        stat.S_IMODE(path.stat().st_mode) in (mode, mode & 0o666) for path in cache.root.rglob("*")
    )
