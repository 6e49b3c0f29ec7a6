"""The joint regime's sampler (equal counts per concept, interleaved, reproducible) and the
DataModules' argument checks and loading from a small generated store."""

from collections import Counter
from types import SimpleNamespace

import pytest
import torch
from helpers.stores import fake_clip, fake_probe

from voe_lightning import specs
from voe_lightning.benchmarks.intphys import IntPhysDataModule
from voe_lightning.benchmarks.physical_concepts import PhysicalConceptsDataModule
from voe_lightning.data import store
from voe_lightning.data.store import render, shards
from voe_lightning.datamodules import ConceptDataModule, VOEDataModule
from voe_lightning.datamodules.voe import InterleavedSampler
from voe_lightning.runs import report_folder


def test_interleaved_sampler_takes_equal_counts_per_part_and_alternates():
    lengths = [5, 8, 6]
    sampler = InterleavedSampler(lengths, shuffle=True, seed=3)
    indices = list(sampler)
    assert len(indices) == len(sampler) == 15
    part_of = lambda i: 0 if i < 5 else (1 if i < 13 else 2)  # noqa: E731
    assert Counter(map(part_of, indices)) == {0: 5, 1: 5, 2: 5}
    # every consecutive round of three holds one index of each part
    for start in range(0, 15, 3):
        assert sorted(map(part_of, indices[start : start + 3])) == [0, 1, 2]
    assert len(set(indices)) == 15


def test_interleaved_sampler_is_reproducible_and_changes_per_epoch():
    first = InterleavedSampler([10, 10], seed=1)
    second = InterleavedSampler([10, 10], seed=1)
    assert list(first) == list(second)
    first.set_epoch(5)
    assert list(first) != list(InterleavedSampler([10, 10], seed=1))


def test_interleaved_sampler_rejects_an_empty_part():
    with pytest.raises(ValueError, match="at least one record"):
        InterleavedSampler([3, 0])


def test_unknown_concept_is_refused_with_the_valid_names():
    with pytest.raises(ValueError, match="valid concepts are: object_persistence"):
        ConceptDataModule(concept="gravity")
    with pytest.raises(ValueError, match="valid concepts are"):
        VOEDataModule(concepts=["continuity", "magnetism"])


def test_datamodule_generates_and_serves_spec_batches(tmp_path):
    datamodule = ConceptDataModule(
        concept="continuity",
        root=str(tmp_path / "data"),
        train_examples=4,
        val_pairs=2,
        test_pairs=2,
        generalization_pairs=2,
        generalization=True,
        batch_size=4,
        probe_batch_size=2,
        generate_workers=1,
        num_frames=8,
        height=32,
        width=32,
    )
    datamodule.prepare_data()
    datamodule.setup("fit")
    batch = next(iter(datamodule.train_dataloader()))
    assert specs.clip_spec(8, 32, 32).expand(4).is_in(batch)
    kinds = {specs.CLIP_KINDS[k] for k in batch["kind"].tolist()}
    assert kinds <= set(specs.CLIP_KINDS_BY_CONCEPT["continuity"])
    probes = next(iter(datamodule.val_dataloader()))
    assert specs.probe_spec(8, 32, 32).expand(2).is_in(probes)
    datamodule.setup("test")
    test_loaders = datamodule.test_dataloader()
    assert len(test_loaders) == 2  # test probes and the three-pillar generalization probes
    generalization = next(iter(test_loaders[1]))
    assert {specs.VARIANTS[v] for v in generalization["variant"].tolist()} == {"three_pillars"}
    assert datamodule.probe_cases("val") == [
        ("continuity", "standard"),
        ("continuity", "counterbalanced"),
        ("continuity", "paper"),
    ]
    assert torch.all(generalization["concept"] == specs.CONCEPTS.index("continuity"))


def test_prepare_data_regenerates_a_checksum_corrupt_shard(tmp_path, monkeypatch):
    """Issue 10 case 4: rerunning fit repairs a corrupt record instead of failing again."""
    monkeypatch.setattr(render, "generate_clip", fake_clip)
    monkeypatch.setattr(render, "generate_probe", fake_probe)
    datamodule = ConceptDataModule(
        concept="continuity", root=str(tmp_path), train_examples=4, val_pairs=1, test_pairs=1,
        generalization_pairs=1, generate_workers=1, num_frames=8, height=16, width=16,
    )  # fmt: skip
    datamodule.prepare_data()
    shard = store.shard_path(tmp_path, "continuity", "train", 0)
    data = bytearray(shard.read_bytes())
    data[len(shards._MAGIC) + 10] ^= 0xFF  # inside the first record
    shard.write_bytes(bytes(data))
    assert store.verify(tmp_path) == [shard]
    with pytest.warns(UserWarning, match=rf"{shard}: record 0 checksum mismatch"):
        datamodule.prepare_data()
    assert store.verify(tmp_path) == []
    first = store.open_split(tmp_path, "continuity", "train")[0]
    expected = fake_clip(
        "continuity", specs.CLIP_KINDS[int(first["kind"])], 0, num_frames=8, height=16, width=16
    )
    assert torch.equal(first["frames"], expected["frames"])


@pytest.mark.parametrize(
    "module, argument, value",
    [(ConceptDataModule, "val_pairs", -1), (ConceptDataModule, "test_pairs", 0),
     (ConceptDataModule, "probe_batch_size", 0), (ConceptDataModule, "num_workers", -2),
     (ConceptDataModule, "generate_workers", 0), (ConceptDataModule, "train_controls", -3),
     (ConceptDataModule, "num_frames", 1), (VOEDataModule, "height", 0),
     (IntPhysDataModule, "num_workers", -1), (IntPhysDataModule, "frame_stride", 0),
     (PhysicalConceptsDataModule, "first_frame", -1), (PhysicalConceptsDataModule, "shuffle_buffer", -1)],
)  # fmt: skip
def test_constructors_refuse_bad_arguments_by_name(module, argument, value):
    """Issue 10 case 11: caught when the DataModule is built, naming the argument."""
    with pytest.raises(
        ValueError, match=rf"^{argument} must be an integer of at least \d+, got {value}$"
    ):
        module(**{argument: value})


def test_constructors_refuse_a_bad_fraction_and_missing_generalization_pairs():
    with pytest.raises(
        ValueError, match=r"divergence_fraction must be a number in \[0, 1\], got 2"
    ):
        IntPhysDataModule(divergence_fraction=2)
    with pytest.raises(
        ValueError, match="generalization_pairs must be an integer of at least 1, got 0"
    ):
        ConceptDataModule(generalization=True, generalization_pairs=0)


@pytest.mark.parametrize("module", [IntPhysDataModule, PhysicalConceptsDataModule])
def test_benchmark_geometry_left_out_is_the_models_or_is_asked_for(module, tmp_path):
    """Issue 10 case 15: num_frames, height and width default to the model's, resolved in
    setup from trainer.lightning_module's hyperparameters; neither given is an error."""
    datamodule = module(root=str(tmp_path))
    with pytest.raises(
        ValueError,
        match=r"num_frames, height, width not given and there is no "
        r"model to take them from; give --data.init_args.num_frames, ",
    ):
        datamodule.setup("test")
    model = SimpleNamespace(hparams={"image_size": [16, 24]})  # a checkpoint from before
    datamodule.trainer = SimpleNamespace(lightning_module=model)
    with pytest.raises(
        ValueError,
        match=r"num_frames not given and the model's hyperparameters "
        r"have no training_frames to take them from; give --data.init_args.num_",
    ):
        datamodule.setup("test")


def test_intphys_takes_the_models_geometry_in_setup(tmp_path):
    from helpers.intphys import FRAMES, make_intphys

    datamodule = IntPhysDataModule(
        root=str(make_intphys(tmp_path, "dev", labelled=True)), frames_per_movie=FRAMES, height=8
    )
    model = SimpleNamespace(hparams={"image_size": [16, 24], "training_frames": 4})
    datamodule.trainer = SimpleNamespace(lightning_module=model)
    datamodule.setup("test")
    batch = next(iter(datamodule.test_dataloader()))
    assert batch["consistent", "frames"].shape[1:] == (4, 8, 24, 3)  # height as given
    assert datamodule.probe_spec().is_in(batch[0])


def _fake_store(tmp_path, monkeypatch, **sizes):
    """A continuity store of fake clips and probes at ``tmp_path`` (16 x 16, 4 frames), the
    DataModule options that made it, and its files' bytes."""
    monkeypatch.setattr(render, "generate_clip", fake_clip)
    monkeypatch.setattr(render, "generate_probe", fake_probe)
    options = dict(
        concept="continuity",
        root=str(tmp_path),
        val_pairs=2,
        generalization_pairs=1,
        generate_workers=1,
        num_frames=8,
        height=16,
        width=16,
        **sizes,
    )
    ConceptDataModule(**options).prepare_data()
    return options, {path: path.read_bytes() for path in tmp_path.rglob("*") if path.is_file()}


def test_a_seed_offset_reads_fresh_probes_from_their_own_store_and_trains_on_the_roots(
    tmp_path, monkeypatch
):
    """Issue 48 part 5: the probe splits of ``seed_offset`` N are generated into and read from
    root/seed_offset_<N>, the training clips from the root, whose store is left as it was."""
    options, before = _fake_store(
        tmp_path, monkeypatch, train_examples=4, test_pairs=3, batch_size=4
    )
    datamodule = ConceptDataModule(**options, seed_offset=1000)
    datamodule.prepare_data()
    assert {path: path.read_bytes() for path in before} == before
    fresh = tmp_path / "seed_offset_1000"
    assert datamodule.probe_source() == {
        "data_root": str(tmp_path),
        "seed_offset": 1000,
        "probe_root": str(fresh),
        "probe_split": "test",
    }
    assert not (fresh / "continuity" / "train").exists() and store.verify(fresh) == []
    datamodule.setup("fit")
    train = [int(seed) for batch in datamodule.train_dataloader() for seed in batch["seed"]]
    assert sorted(train) == list(range(8))  # the root's training clips, unshifted
    val = [int(seed) for batch in datamodule.val_dataloader() for seed in batch["seed"]]
    assert sorted(set(val)) == [store.SEED_STARTS["val"] + 1000 + k for k in range(2)]
    datamodule.setup("test")
    test = next(iter(datamodule.test_dataloader()))
    assert set(test["seed"].tolist()) == {store.SEED_STARTS["test"] + 1000 + k for k in range(3)}


def test_test_split_val_reports_on_the_validation_probes_in_a_folder_of_its_own(
    tmp_path, monkeypatch
):
    """Tuning reads the validation probes' quadruplets through ``test`` (``test_split: val``),
    never the test probes, and its report cannot land in the run's own folder."""
    monkeypatch.setattr(render, "generate_clip", fake_clip)
    monkeypatch.setattr(render, "generate_probe", fake_probe)
    options = dict(
        concept="continuity",
        root=str(tmp_path),
        train_examples=2,
        val_pairs=2,
        test_pairs=3,
        generalization_pairs=1,
        generalization=True,
        generate_workers=1,
        num_frames=8,
        height=16,
        width=16,
    )
    datamodule = ConceptDataModule(**options, test_split="val")
    datamodule.prepare_data()
    datamodule.setup("test")
    loader = datamodule.test_dataloader()  # one loader: no generalization probes with val
    seeds = {int(seed) for batch in loader for seed in batch["seed"]}
    assert seeds == {store.SEED_STARTS["val"] + k for k in range(2)}
    assert datamodule.probe_source()["probe_split"] == "val"
    checkpoint = tmp_path / "runs" / "r" / "version_0" / "checkpoints" / "last.ckpt"
    root = str(tmp_path)
    assert report_folder(checkpoint, root, None, None, root, None) is None
    assert report_folder(checkpoint, root, None, None, root, None, split="val").startswith(
        "val_probes-"
    )
    with pytest.raises(ValueError, match=r"test_split must be one of \('test', 'val'\).*'train'"):
        ConceptDataModule(**options, test_split="train")


def test_a_seed_offset_past_a_splits_range_is_refused_when_built():
    last = store.SEED_RANGE - 3
    pairs = dict(val_pairs=3, test_pairs=3, generalization_pairs=1)
    ConceptDataModule(**pairs, seed_offset=last)
    with pytest.raises(
        ValueError,
        match=r"the test split would need seeds up to 3_000_000_000 "
        r".*seed_offset plus the count must be at most 1_000_000_000",
    ):
        ConceptDataModule(**{**pairs, "test_pairs": 4}, seed_offset=last)
    with pytest.raises(
        ValueError,
        match=r"seed_offset must be an integer in \[0, 999_999_999\]"
        r".*got -5",
    ):
        VOEDataModule(seed_offset=-5)


def test_train_limit_trains_on_a_prefix_of_the_store_with_every_kind_in_proportion(
    tmp_path, monkeypatch
):
    """``train_limit`` N reads the first N examples per concept and their controls in
    proportion from the same store (a training-size sweep without regenerating), and refuses
    a limit outside 1..train_examples."""
    options, before = _fake_store(
        tmp_path, monkeypatch, train_examples=8, test_pairs=2, batch_size=2
    )
    datamodule = ConceptDataModule(**options, train_limit=4)
    datamodule.prepare_data()
    datamodule.setup("fit")
    assert {path: path.read_bytes() for path in before} == before  # the same store
    batches = list(datamodule.train_dataloader())
    kinds = [specs.CLIP_KINDS[int(k)] for batch in batches for k in batch["kind"]]
    seeds = sorted(int(seed) for batch in batches for seed in batch["seed"])
    assert seeds == list(range(8))  # the first 8 of the 16 clips: 4 examples, 4 controls
    assert kinds.count("example") == 4
    assert set(kinds) == set(specs.CLIP_KINDS_BY_CONCEPT["continuity"])
    for bad in (0, 9):
        with pytest.raises(
            ValueError, match=rf"train_limit must be .* from 1 to train_examples \(8\).*got {bad}"
        ):
            ConceptDataModule(**options, train_limit=bad)
