"""Dataset generation: the shard plan (disjoint seeds, 1:1 controls, slices that cover the work
once), resuming, repairing corrupt shards, refusing other settings, bad input, and a real
two-worker run of the MuJoCo scenes."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from helpers.stores import fake_clip, fake_probe

from voe_lightning import scenes, specs
from voe_lightning.cli import main
from voe_lightning.data import store
from voe_lightning.data.store import files, manifest, plan, render

SMALL = dict(
    train_examples=4,
    val_pairs=2,
    test_pairs=3,
    generalization_pairs=1,
    shard_size=3,
    num_frames=8,
    height=24,
    width=24,
    workers=1,
    progress=False,
)
CONCEPTS = ("unchangeableness", "continuity")


@pytest.fixture
def calls(monkeypatch):
    """Replace the MuJoCo scenes with fast structured fakes and record every call."""
    made = []

    def clip(concept, kind, seed, **options):
        made.append((concept, "clip", kind, seed))
        return fake_clip(concept, kind, seed, **options)

    def probe(concept, variant, seed, **options):
        made.append((concept, "probe", variant, seed))
        return fake_probe(concept, variant, seed, **options)

    monkeypatch.setattr(render, "generate_clip", clip)
    monkeypatch.setattr(render, "generate_probe", probe)
    return made


def _plan(**overrides):
    counts = dict(train_examples=10, train_controls=None, val_pairs=3,
                  test_pairs=4, generalization_pairs=2)  # fmt: skip
    counts.update(overrides)
    if counts["train_controls"] is None:
        counts["train_controls"] = counts["train_examples"]
    per_concept = {c: store.split_counts(c, **counts) for c in specs.CONCEPTS}
    return store.plan_shards(per_concept, shard_size=4)


def test_plan_matches_controls_one_to_one_and_keeps_splits_disjoint():
    tasks = _plan(train_examples=10)
    train = [
        item
        for t in tasks
        if t.concept == "object_persistence" and t.split == "train"
        for item in t.items
    ]
    kinds = [kind for kind, _ in train]
    assert kinds.count("example") == 10
    assert kinds.count("plank_beside_object") == kinds.count("plank_on_empty_floor") == 5
    assert set(kinds[:4]) == set(specs.CLIP_KINDS_BY_CONCEPT["object_persistence"])  # interleaved
    for concept in specs.CONCEPTS:
        seeds = {
            split: {
                seed for t in tasks if t.concept == concept and t.split == split for seed in t.seeds
            }
            for split in store.SPLITS
        }
        for split, own in seeds.items():
            start = store.SEED_STARTS[split]
            assert all(start <= seed < start + store.SEED_RANGE for seed in own)
            assert all(not own & other for name, other in seeds.items() if name != split)
    # A probe split gives every variant the same seeds: a seed names a quadruplet.
    test = [
        item
        for t in tasks
        if t.concept == "object_persistence" and t.split == "test"
        for item in t.items
    ]
    by_variant = {
        v: sorted(seed for name, seed in test if name == v)
        for v in specs.STANDARD_VARIANTS["object_persistence"]
    }
    start = store.SEED_STARTS["test"]
    assert by_variant == {v: list(range(start, start + 4)) for v in by_variant}
    unchangeableness = [t for t in tasks if t.concept == "unchangeableness"]
    variants = {v for t in unchangeableness if t.split == "generalization" for v, _ in t.items}
    assert variants == set(specs.GENERALIZATION_VARIANTS["unchangeableness"])
    assert not [t for t in tasks if t.concept == "solidity" and t.split == "generalization"]


def test_slices_cover_every_shard_exactly_once(tmp_path, calls):
    full = [(t.concept, t.split, t.index) for t in _plan()]
    sliced = [(t.concept, t.split, t.index) for k in range(3) for t in _plan()[k::3]]
    assert sorted(sliced) == sorted(full) and len(set(sliced)) == len(full)
    summaries = [
        store.generate_dataset(tmp_path, CONCEPTS, shard_index=k, num_shards=3, **SMALL)
        for k in range(3)
    ]
    assert (
        sum(s.shards_generated for s in summaries)
        == summaries[0].shards_planned + summaries[1].shards_planned + summaries[2].shards_planned
    )
    assert len(calls) == len(set(calls))  # no record rendered twice
    assert store.verify(tmp_path) == []
    assert store.generate_dataset(tmp_path, CONCEPTS, **SMALL).shards_generated == 0
    with pytest.raises(ValueError, match=r"shard_index must be in \[0, 2\], got 3"):
        store.generate_dataset(tmp_path, CONCEPTS, shard_index=3, num_shards=3, **SMALL)


def test_round_trip_resume_and_repair(tmp_path, calls):
    first = store.generate_dataset(tmp_path, CONCEPTS, **SMALL)
    assert first.shards_generated == first.shards_planned and first.records_generated == len(calls)
    train = store.open_split(tmp_path, "continuity", "train")
    assert len(train) == 8
    for index in range(len(train)):
        record = train[index]
        kind = specs.CLIP_KINDS[int(record["kind"])]
        expected = fake_clip(
            "continuity", kind, int(record["seed"]), num_frames=8, height=24, width=24
        )
        assert all(torch.equal(record[k], expected[k]) for k in expected.keys(True, True))
    test = store.open_split(tmp_path, "unchangeableness", "test")
    variants = specs.STANDARD_VARIANTS["unchangeableness"]
    assert len(test) == 3 * len(variants) and test.spec.is_in(test[4])
    assert {specs.VARIANTS[int(test[i]["variant"])] for i in range(len(test))} == set(variants)
    before = test[6]

    calls.clear()  # rerun: nothing to do
    assert (
        store.generate_dataset(tmp_path, CONCEPTS, **SMALL).shards_skipped == first.shards_planned
    )
    assert calls == []
    assert store.ensure_dataset(tmp_path, concepts=CONCEPTS, **SMALL) is None

    missing = store.shard_path(tmp_path, "continuity", "train", 1)
    missing.unlink()
    corrupt = store.shard_path(tmp_path, "unchangeableness", "test", 2)
    data = bytearray(corrupt.read_bytes())
    data[20] ^= 0x01
    corrupt.write_bytes(bytes(data))
    with pytest.raises(store.CorruptShardError, match=str(corrupt)):
        store.open_split(tmp_path, "unchangeableness", "test")[6]  # first record of shard 2
    assert sorted(store.verify(tmp_path)) == sorted([corrupt, missing])
    repaired = store.generate_dataset(tmp_path, CONCEPTS, **SMALL)
    assert repaired.shards_generated == 2 and repaired.records_generated == len(calls) == 3 + 3
    assert store.verify(tmp_path) == []
    assert torch.equal(
        store.open_split(tmp_path, "unchangeableness", "test")[6]["inconsistent", "frames"],
        before["inconsistent", "frames"],
    )


def test_ensure_dataset_generates_only_what_is_missing(tmp_path, calls):
    store.ensure_dataset(tmp_path, concepts=("continuity",), **SMALL)
    made = len(calls)
    assert made == 8 + 2 * 3 + 3 * 3 + 1  # three standard variants, one generalization
    store.shard_path(tmp_path, "continuity", "val", 0).unlink()
    summary = store.ensure_dataset(tmp_path, concepts=("continuity",), **SMALL)
    assert summary.shards_generated == 1 and len(calls) == made + 3
    # Another concept joins the same root; the first is left alone.
    store.ensure_dataset(tmp_path, concepts=("containment",), **SMALL)
    assert set(json.loads((tmp_path / "manifest.json").read_text())["concepts"]) == {
        "continuity",
        "containment",
    }
    with pytest.raises(TypeError, match="frames_per_video"):
        store.ensure_dataset(tmp_path, frames_per_video=3)


def test_a_generate_plans_the_store_once(tmp_path, calls, monkeypatch):
    """ensure_dataset finds a shard missing and renders it from the one plan it checked the
    store with."""
    store.generate_dataset(tmp_path, ("continuity",), **SMALL)
    store.shard_path(tmp_path, "continuity", "val", 0).unlink()
    planned = []

    def plan_shards(*arguments, **options):
        planned.append(arguments)
        return store.plan_shards(*arguments, **options)

    monkeypatch.setattr(plan, "plan_shards", plan_shards)
    summary = store.ensure_dataset(tmp_path, concepts=("continuity",), **SMALL)
    assert summary.shards_generated == 1 and store.verify(tmp_path) == []
    assert len(planned) == 1


def test_ensure_dataset_of_some_splits_leaves_the_rest_to_a_later_run(tmp_path, calls):
    """Issue 10 case 9: a test run makes only its probes; a later fit completes the store."""
    store.ensure_dataset(tmp_path, concepts=("continuity",), splits=("test",), **SMALL)
    assert {kind for _, kind, _, seed in calls} == {"probe"} and len(calls) == 3 * 3
    assert {path.name for path in (tmp_path / "continuity").iterdir()} == {"test"}
    assert (
        store.ensure_dataset(tmp_path, concepts=("continuity",), splits=("test",), **SMALL) is None
    )
    store.ensure_dataset(tmp_path, concepts=("continuity",), **SMALL)
    assert len(calls) == 8 + 2 * 3 + 3 * 3 + 1 and store.verify(tmp_path) == []
    with pytest.raises(ValueError, match="unknown split 'tests'; valid splits are: train"):
        store.ensure_dataset(tmp_path, concepts=("continuity",), splits=("tests",), **SMALL)


def test_other_settings_are_refused_unless_overwritten(tmp_path, calls):
    store.generate_dataset(tmp_path, ("continuity",), **SMALL)
    with pytest.raises(store.ManifestMismatchError, match=r"video.height: stored 24, asked 32"):
        store.generate_dataset(tmp_path, ("continuity",), **{**SMALL, "height": 32})
    with pytest.raises(store.ManifestMismatchError, match=r"kinds.example: stored 4, asked 5"):
        store.generate_dataset(tmp_path, ("continuity",), **{**SMALL, "train_examples": 5})
    summary = store.generate_dataset(
        tmp_path, ("continuity",), **{**SMALL, "height": 32, "overwrite": True}
    )
    assert summary.shards_skipped == 0 and store.verify(tmp_path) == []
    assert store.open_split(tmp_path, "continuity", "train")[0]["frames"].shape == (8, 32, 24, 3)


def test_bad_input_names_the_value_and_the_choices(tmp_path, calls, capsys):
    with pytest.raises(
        ValueError,
        match="unknown concept 'gravity'; valid concepts are: object_persistence, unchangeableness, continuity, solidity, containment",
    ):
        store.generate_dataset(tmp_path, ("continuity", "gravity"), **SMALL)
    with pytest.raises(ValueError, match="train_examples must be a non-negative integer, got -1"):
        store.generate_dataset(tmp_path, ("continuity",), **{**SMALL, "train_examples": -1})
    with pytest.raises(SystemExit):
        main(["generate", "--root", str(tmp_path), "--concepts", "[continuity, gravity]"])
    assert capsys.readouterr().err == (  # refused in one line with the valid names
        "error: --concepts: expected one of object_persistence, unchangeableness, continuity, "
        "solidity, containment, got gravity\n"
    )
    with pytest.raises(SystemExit):
        main(
            [
                "generate",
                "--root",
                str(tmp_path),
                "--concepts",
                "[continuity]",
                "--train_examples",
                "-1",
            ]
        )
    assert "error: train_examples must be a non-negative integer, got -1" in capsys.readouterr().err
    assert not (tmp_path / "manifest.json").exists()
    not_a_folder = tmp_path / "file"
    not_a_folder.write_text("")
    with pytest.raises(OSError, match=str(not_a_folder / "data")):
        store.generate_dataset(not_a_folder / "data", ("continuity",), **SMALL)


def test_full_disk_names_the_shard(tmp_path, calls, monkeypatch):
    def full_disk(file, data):
        raise OSError(28, "No space left on device")

    store.generate_dataset(tmp_path, ("continuity",), **SMALL)
    lost = store.shard_path(tmp_path, "continuity", "test", 0)
    lost.unlink()
    monkeypatch.setattr(files, "_write_bytes", full_disk)
    with pytest.raises(OSError, match=f"cannot write {lost}: No space left on device"):
        store.generate_dataset(tmp_path, ("continuity",), **SMALL)
    assert not list(lost.parent.glob("*.tmp"))  # no temporary left behind


def test_command_line_generates_with_real_scenes_in_two_workers(tmp_path):
    """End to end with MuJoCo in two spawned worker processes (tiny videos)."""
    root = tmp_path / "data"
    argv = ["generate", "--root", str(root), "--concepts", "[continuity]",
            "--train_examples", "2", "--val_pairs", "1", "--test_pairs", "1",
            "--generalization_pairs", "1", "--shard_size", "1", "--workers", "2",
            "--height", "32", "--width", "32", "--progress", "false"]  # fmt: skip
    summary = main(argv)
    assert summary.shards_generated == summary.shards_planned == 11
    assert store.verify(root) == []
    val = store.open_split(root, "continuity", "val")[0]
    expected = scenes.generate_probe(
        "continuity", "standard", store.SEED_STARTS["val"], height=32, width=32
    )
    assert torch.equal(val["inconsistent", "frames"], expected["inconsistent", "frames"])
    assert main(argv).shards_generated == 0


def test_shards_must_prove_they_belong_to_the_plan(tmp_path, calls, monkeypatch):
    """Issue 10 case 1: seeds alone do not make a shard the planned one."""
    store.generate_dataset(tmp_path, CONCEPTS, **SMALL)
    planned = len(
        store.plan_shards({"continuity": store.split_counts("continuity", 4, 4, 2, 3, 1)}, 3)
    )
    # Record spec: same seeds, other video size, manifest lost.
    (tmp_path / "manifest.json").unlink()
    with pytest.warns(
        UserWarning, match=r"frames is uint8\[8, 24, 24, 3\], expected uint8\[8, 32, 24, 3\]"
    ):
        summary = store.generate_dataset(tmp_path, ("continuity",), **{**SMALL, "height": 32})
    assert summary.shards_generated == planned and summary.shards_skipped == 0
    assert store.open_split(tmp_path, "continuity", "train")[0]["frames"].shape == (8, 32, 24, 3)
    assert store.verify(tmp_path) == []
    # Kinds per record: same seeds, other kind counts.
    (tmp_path / "manifest.json").unlink()
    with pytest.warns(
        UserWarning, match=r"train/shard-00000.voe: does not belong here: its names is"
    ):
        store.generate_dataset(
            tmp_path,
            ("continuity",),
            **{**SMALL, "height": 32, "train_examples": 2, "train_controls": 6},
        )
    kinds = [
        specs.CLIP_KINDS[int(r["kind"])] for r in store.open_split(tmp_path, "continuity", "train")
    ]
    assert kinds.count("example") == 2
    # Concept: a shard of another concept with the same seeds (three variants) in its place.
    store.generate_dataset(
        tmp_path,
        ("containment", "unchangeableness"),
        **{**SMALL, "height": 32, "train_examples": 2, "train_controls": 6},
    )
    foreign = store.shard_path(tmp_path, "continuity", "test", 0)
    foreign.write_bytes(store.shard_path(tmp_path, "unchangeableness", "test", 0).read_bytes())
    assert store.verify(tmp_path) == [foreign]
    with pytest.warns(
        UserWarning, match=r"its concept is 'unchangeableness', expected 'continuity'"
    ):
        assert (
            store.generate_dataset(
                tmp_path,
                ("continuity",),
                **{**SMALL, "height": 32, "train_examples": 2, "train_controls": 6},
            ).shards_generated
            == 1
        )
    assert specs.concept_name(store.open_split(tmp_path, "continuity", "test")[0]) == "continuity"
    # Generator version: a scene change makes every shard stale.
    version = store.GENERATOR_VERSION
    for module in (plan, manifest):  # where shards and manifests take it from
        monkeypatch.setattr(module, "GENERATOR_VERSION", version + 1)
    assert len(store.verify(tmp_path)) == len(store.manifest_plan(store.read_manifest(tmp_path))[0])
    options = {**SMALL, "height": 32, "train_examples": 2, "train_controls": 6}
    with pytest.warns(
        UserWarning, match=f"its generator_version is {version}, expected {version + 1}"
    ):
        summary = store.ensure_dataset(
            tmp_path, concepts=("continuity", "containment", "unchangeableness"), **options
        )
    assert summary.shards_skipped == 0 and store.verify(tmp_path) == []
    assert store.read_manifest(tmp_path)["generator_version"] == version + 1


def test_shards_without_object_states_are_regenerated(tmp_path, calls):
    """A shard written before records carried object states (GENERATOR_VERSION 2) does not
    match the record layout: verify finds it and generate rewrites it with them."""
    store.generate_dataset(tmp_path, ("continuity",), **SMALL)
    layouts = store.record_layouts(scenes.VideoOptions(num_frames=8, height=24, width=24))
    assert "objects/visible_fraction" in layouts["clip"]
    assert "inconsistent/objects/shape_label" in layouts["probe"]
    for split in ("train", "test"):
        path = store.shard_path(tmp_path, "continuity", split, 0)
        reader = store.ShardReader(path)
        records = [reader[i] for i in range(len(reader))]
        meta = reader.index.meta
        reader.close()
        stripped = [
            r.exclude("objects", ("consistent", "objects"), ("inconsistent", "objects"))
            for r in records
        ]
        store.write_shard(path, stripped, meta)
    stale = {store.shard_path(tmp_path, "continuity", split, 0) for split in ("train", "test")}
    assert set(store.verify(tmp_path)) == stale
    with pytest.warns(UserWarning, match=r"its records' (consistent/)?objects/color is missing"):
        summary = store.generate_dataset(tmp_path, ("continuity",), **SMALL)
    assert summary.shards_generated == 2 and store.verify(tmp_path) == []
    assert ("objects", "position") in store.open_split(tmp_path, "continuity", "train")[0].keys(
        True
    )


def _children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid`` (from /proc)."""
    found = []
    for stat_file in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat_file.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat_file.parent.name))
    return found


def _command_line(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc to find the workers")
@pytest.mark.slow
def test_workers_die_with_a_killed_parent(tmp_path):
    """Issue 10 case 2: kill -9 of generate leaves no worker (nor resource tracker) rendering.
    Shards of 40 records take seconds each, so an orphan worker would outlive the 1.5 s
    allowed. The resource tracker renders nothing and leaves when its pipe closes, after its
    clean-up: 2.7 s on a 2-core machine busy with two fits, so it gets 10 s."""
    root = tmp_path / "data"
    command = [sys.executable, "-m", "voe_lightning", "generate", "--root", str(root),
               "--concepts", "[continuity]", "--train_examples", "200", "--val_pairs", "0",
               "--test_pairs", "0", "--generalization_pairs", "0", "--shard_size", "40",
               "--workers", "2", "--num_frames", "3", "--height", "16", "--width", "16",
               "--progress", "false"]  # fmt: skip
    parent = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    children = []
    try:
        deadline = time.monotonic() + 120
        while not list(root.glob("continuity/train/shard-*.voe")):  # the workers are rendering
            assert parent.poll() is None and time.monotonic() < deadline, (
                "generate never wrote a shard"
            )
            time.sleep(0.1)
        children = _children(parent.pid)
        assert len(children) >= 2  # two workers (and the resource tracker)
        trackers = [pid for pid in children if b"resource_tracker" in _command_line(pid)]
        parent.kill()
        parent.wait()
        time.sleep(1.5)
        assert [pid for pid in children if _alive(pid) and pid not in trackers] == []
        deadline = time.monotonic() + 10
        while any(map(_alive, trackers)) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert [pid for pid in trackers if _alive(pid)] == []
    finally:
        parent.kill()
        for pid in filter(_alive, children):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize(
    "text, message",
    [("{}", r"bad video \(missing\), shard_size \(missing\), concepts \(missing\)"),
     ("[]", "holds a JSON list"), ("null", "holds a JSON null"),
     ('{"video": {"num_frames": 6', r"unreadable manifest .* \(truncated\?\)"),
     ('{"video": {}, "shard_size": "3", "concepts": {}}', r"bad shard_size \(a str\)")],
)  # fmt: skip
def test_a_malformed_manifest_is_named_and_overwritten_on_request(tmp_path, calls, text, message):
    """Issue 10 case 5: wrong-shape, null or truncated manifests raise a named error, and
    --overwrite replaces them."""
    store.generate_dataset(tmp_path, ("continuity",), **SMALL)
    stored = tmp_path / "manifest.json"
    stored.write_text(text)
    path = str(stored)
    with pytest.raises(store.ManifestError, match=message) as error:
        store.generate_dataset(tmp_path, ("continuity",), **SMALL)
    assert path in str(error.value)
    with pytest.raises(store.ManifestError, match="--overwrite"):
        store.open_split(tmp_path, "continuity", "train")
    with pytest.raises(store.ManifestError, match=path):
        store.verify(tmp_path)
    calls.clear()
    summary = store.generate_dataset(tmp_path, ("continuity",), **{**SMALL, "overwrite": True})
    assert (
        summary.shards_skipped == summary.shards_planned and calls == []
    )  # the shards still belong
    assert store.verify(tmp_path) == [] and store.read_manifest(tmp_path)["shard_size"] == 3


# --- seed offset (issue 48 part 5: a fresh test set anyone can re-test a checkpoint on) -------
OFFSET = 1_000_000
PROBES_ONLY = {**SMALL, "train_examples": 0}


def _store_files(root: Path) -> dict[str, bytes]:
    return {
        str(path.relative_to(root)): path.read_bytes()
        for path in sorted(root.rglob("*"))
        if path.is_file()
    }


def test_an_offset_shifts_the_probe_seeds_within_their_split_and_never_the_clips():
    tasks = _plan()
    shifted = store.plan_shards(
        {c: store.split_counts(c, 10, 10, 3, 4, 2) for c in specs.CONCEPTS}, 4, OFFSET
    )
    for task, moved in zip(tasks, shifted, strict=True):
        assert (
            moved.items == task.items
            if task.split == "train"
            else moved.seeds == [seed + OFFSET for seed in task.seeds]
        )
        assert ("seed_offset" in store.shard_meta(moved)) == (task.split != "train")
        assert "seed_offset" not in store.shard_meta(task)  # stores before offsets stay
    last = store.SEED_RANGE - 4  # 4 test pairs per variant fit exactly
    edge = store.plan_shards({"solidity": store.split_counts("solidity", 0, 0, 0, 4, 0)}, 4, last)
    assert max(seed for t in edge for seed in t.seeds) == store.SEED_STARTS["generalization"] - 1
    with pytest.raises(
        ValueError,
        match=r"solidity: the test split would need seeds up to "
        r"3_000_000_000 .*past the last seed of its range, 2_999_999_999: "
        r"seed_offset plus the count must be at most 1_000_000_000",
    ):
        store.plan_shards({"solidity": store.split_counts("solidity", 0, 0, 0, 5, 0)}, 4, last)
    for bad in (-1, store.SEED_RANGE, 1.5, True):
        with pytest.raises(
            ValueError,
            match=rf"seed_offset must be an integer in \[0, "
            rf"999_999_999\].*got {bad!r}",
        ):
            store.check_seed_offset(bad)


def test_an_offset_store_is_its_own_beside_the_root_resumable_and_checked(tmp_path, calls):
    store.generate_dataset(tmp_path, ("continuity",), **SMALL)
    before = _store_files(tmp_path)
    calls.clear()
    summary = store.generate_dataset(tmp_path, ("continuity",), **PROBES_ONLY, seed_offset=OFFSET)
    fresh = tmp_path / f"seed_offset_{OFFSET}"
    assert summary.root == fresh and store.verify(fresh) == []
    assert {
        str(p.relative_to(tmp_path))
        for p in tmp_path.rglob("*")
        if p.is_file() and fresh not in p.parents
    } == set(before)  # the root's store is untouched
    assert _store_files(tmp_path).items() >= before.items()
    assert {kind for _, kind, _, _ in calls} == {"probe"}  # no training clips in it
    manifest = store.read_manifest(fresh)
    assert manifest["seed_offset"] == OFFSET
    assert manifest["concepts"]["continuity"]["splits"]["test"]["seed_start"] == (
        store.SEED_STARTS["test"] + OFFSET
    )
    for split in ("val", "test", "generalization"):
        seeds = [int(r["seed"]) for r in store.open_split(fresh, "continuity", split)]
        old = [int(r["seed"]) for r in store.open_split(tmp_path, "continuity", split)]
        assert seeds == [seed + OFFSET for seed in old]
        assert (
            store.ShardReader(store.shard_path(fresh, "continuity", split, 0)).index.meta[
                "seed_offset"
            ]
            == OFFSET
        )
    # Resumable: a rerun keeps it; a lost shard is rendered again at the offset's seeds.
    lost = store.shard_path(fresh, "continuity", "test", 0)
    lost.unlink()
    again = store.generate_dataset(tmp_path, ("continuity",), **PROBES_ONLY, seed_offset=OFFSET)
    assert again.shards_generated == 1 and store.verify(fresh) == []
    assert (
        store.ensure_dataset(tmp_path, concepts=("continuity",), seed_offset=OFFSET, **PROBES_ONLY)
        is None
    )
    # Training clips are not shifted: an offset store refuses them, before any work.
    with pytest.raises(
        ValueError,
        match=rf"seed_offset {OFFSET} draws fresh probes only, into "
        rf"{fresh}.*give train_examples 0 and train_controls 0, got 4 and 4",
    ):
        store.generate_dataset(tmp_path, ("continuity",), **SMALL, seed_offset=OFFSET)


def test_a_store_of_another_offset_is_refused_and_its_shards_found(tmp_path, calls):
    store.generate_dataset(tmp_path / "a", ("continuity",), **PROBES_ONLY, seed_offset=OFFSET)
    moved = tmp_path / "b" / "seed_offset_7"  # a store copied to another offset's place
    moved.parent.mkdir()
    (tmp_path / "a" / f"seed_offset_{OFFSET}").rename(moved)
    with pytest.raises(
        store.ManifestMismatchError, match=rf"seed_offset: stored {OFFSET}, asked 7"
    ):
        store.generate_dataset(tmp_path / "b", ("continuity",), **PROBES_ONLY, seed_offset=7)
    with pytest.raises(
        store.ManifestMismatchError, match=rf"seed_offset: stored {OFFSET}, asked 0"
    ):
        store.generate_dataset(moved, ("continuity",), **PROBES_ONLY)
    summary = store.generate_dataset(
        tmp_path / "b", ("continuity",), **PROBES_ONLY, seed_offset=7, overwrite=True
    )
    assert summary.root == moved and summary.shards_skipped == 0
    assert store.read_manifest(moved)["seed_offset"] == 7 and store.verify(moved) == []
    # A shard of the store at offset 0 in the offset store's place is found by what it is.
    store.generate_dataset(tmp_path / "c", ("continuity",), **PROBES_ONLY)
    foreign = store.shard_path(moved, "continuity", "test", 0)
    foreign.write_bytes(store.shard_path(tmp_path / "c", "continuity", "test", 0).read_bytes())
    assert store.verify(moved) == [foreign]
    with pytest.warns(UserWarning, match="its seed_offset is missing, expected 7"):
        store.generate_dataset(tmp_path / "b", ("continuity",), **PROBES_ONLY, seed_offset=7)


def test_command_line_draws_fresh_real_probes_at_an_offset(tmp_path, capsys):
    """MuJoCo: the offset's probes are the scenes of the shifted seeds, and other videos."""
    root = tmp_path / "data"
    argv = ["generate", "--root", str(root), "--concepts", "[solidity]", "--val_pairs", "0",
            "--test_pairs", "1", "--generalization_pairs", "0", "--shard_size", "2",
            "--workers", "1", "--num_frames", "6", "--height", "32", "--width", "32",
            "--progress", "false"]  # fmt: skip
    main([*argv, "--train_examples", "0"])
    summary = main([*argv, "--seed_offset", str(OFFSET)])
    assert summary.root == root / f"seed_offset_{OFFSET}"
    assert str(summary.root) in capsys.readouterr().out  # says where
    seed = store.SEED_STARTS["test"] + OFFSET
    for old, new in zip(
        store.open_split(root, "solidity", "test"),
        store.open_split(summary.root, "solidity", "test"),
        strict=True,
    ):
        variant = specs.VARIANTS[int(new["variant"])]
        expected = scenes.generate_probe(
            "solidity", variant, seed, num_frames=6, height=32, width=32
        )
        assert int(new["seed"]) == seed
        assert torch.equal(new["consistent", "frames"], expected["consistent", "frames"])
        assert not torch.equal(new["consistent", "frames"], old["consistent", "frames"])
