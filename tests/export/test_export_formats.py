"""The three export formats of a real MuJoCo store (all five concepts, 2 quadruplets each, 8
frames of 32x32), read back by the package's own IntPhys and IntPhys 2 readers and by
``read_webdataset``: the same pairs, labels, quadruplet grouping and frames (exact for PNG and
npy; within the stated codec error for mp4), manifests whose checksums are the files', and
byte-identical exports of one store."""

import csv
import io
import json
import os
import tarfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from voe_lightning import specs
from voe_lightning.benchmarks.intphys import export as intphys_export
from voe_lightning.benchmarks.intphys import reader as intphys
from voe_lightning.benchmarks.intphys2 import export as intphys2_export
from voe_lightning.benchmarks.intphys2 import reader as intphys2
from voe_lightning.benchmarks.mp4 import ClipSampling
from voe_lightning.benchmarks.reader import FrameSampling, SkipLog, first_divergence
from voe_lightning.data import store
from voe_lightning.data.store import GENERATOR_VERSION, generate_dataset
from voe_lightning.export.command import export
from voe_lightning.export.manifest import MANIFEST_NAME, sha256_file
from voe_lightning.export.webdataset import read_webdataset

FRAMES, SIZE, PAIRS = 8, 32, 2
SAMPLING = FrameSampling(tuple(range(FRAMES)), SIZE, SIZE)
FORMATS = ("intphys2", "intphys", "webdataset")


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """A real store: the test split of every concept, PAIRS seeds per variant."""
    folder = tmp_path_factory.mktemp("store")
    generate_dataset(
        folder, train_examples=0, val_pairs=0, test_pairs=PAIRS, generalization_pairs=0,
        workers=1, num_frames=FRAMES, height=SIZE, width=SIZE, progress=False,
        splits=("test",),
    )  # fmt: skip
    return folder


@pytest.fixture(scope="module")
def records(root):
    """Every test record of the store, by (concept, variant, seed)."""
    found = {}
    for concept in specs.CONCEPTS:
        dataset = store.open_split(root, concept, "test")
        for index in range(len(dataset)):
            record = dataset[index]
            found[(concept, specs.variant_name(record), int(record["seed"]))] = record
    return found


@pytest.fixture(scope="module")
def exports(root, tmp_path_factory):
    """Each format's export of the store: format -> (folder, manifest)."""
    made = {}
    for export_format in FORMATS:
        out = tmp_path_factory.mktemp("exports") / export_format
        made[export_format] = (out, export(root, export_format, out, progress=False))
    return made


def store_pair(records, concept, entry):
    """The store record of a manifest pair entry of ``concept``'s group at ``seed``."""
    return records[(concept, entry["variant"], entry["seed"])]


def manifest_pairs(manifest, concept):
    """(group entry, pair entry, half) of every pair of ``concept`` in a manifest."""
    groups = manifest["quadruplets"] + manifest["pairs"]
    return [
        (group, {**pair, "seed": group["seed"]}, half)
        for group in groups
        if group["concept"] == concept
        for half, pair in enumerate(group["pairs"])
    ]


def test_every_format_holds_every_concepts_quadruplets_and_lone_pairs(exports, records):
    lone = {(c, v, s) for c, v, s in records if v in specs.REPORTED_BESIDE}
    assert len(lone) == PAIRS  # continuity's paper variant
    for export_format, (_, manifest) in exports.items():
        quadruplets = manifest["quadruplets"]
        assert {q["concept"] for q in quadruplets} == set(specs.CONCEPTS)
        expected = sum(len(rows) for rows in specs.QUADRUPLETS.values()) * PAIRS
        assert len(quadruplets) == expected
        for quadruplet in quadruplets:
            halves = specs.QUADRUPLETS[quadruplet["concept"]][quadruplet["quadruplet"]]
            assert [pair["variant"] for pair in quadruplet["pairs"]] == list(halves)
            assert quadruplet["consistent"] == [pair["consistent"] for pair in quadruplet["pairs"]]
            assert quadruplet["inconsistent"] == [p["inconsistent"] for p in quadruplet["pairs"]]
            assert len(set(quadruplet["consistent"] + quadruplet["inconsistent"])) == 4
        kept = {(p["concept"], p["pairs"][0]["variant"], p["seed"]) for p in manifest["pairs"]}
        left = {(p["concept"], p["variant"], p["seed"]) for p in manifest["left_out"]}
        assert (kept, left) == ((set(), lone) if export_format == "intphys" else (lone, set()))


def test_manifests_cite_the_probes_and_checksum_every_file(exports, root):
    for export_format, (out, manifest) in exports.items():
        assert (
            manifest["citation"]
            == f"voe_lightning probes v{GENERATOR_VERSION}, test split, seed offset 0"
        )
        assert manifest["generator_version"] == GENERATOR_VERSION
        assert (manifest["export_format"], manifest["split"], manifest["seed_offset"]) == (
            export_format, "test", 0,
        )  # fmt: skip
        assert manifest["store"]["manifest_sha256"] == sha256_file(root / store.MANIFEST_NAME)
        assert manifest["seeds"]["solidity"] == {
            "seed_start": 2_000_000_000,
            "seed_stop": 2_000_000_000 + PAIRS,
            "variants": {"standard": PAIRS, "counterbalanced": PAIRS},
        }
        assert json.loads((out / MANIFEST_NAME).read_text()) == manifest
        on_disk = {
            path.relative_to(out).as_posix()
            for path in out.rglob("*")
            if path.is_file() and path.name != MANIFEST_NAME
        }
        assert set(manifest["files"]) == on_disk
        assert all(sha256_file(out / name) == sha for name, sha in manifest["files"].items())


def test_intphys2_reader_reads_the_pairs_labels_quadruplets_and_frames_back(exports, records):
    out, manifest = exports["intphys2"]
    bound = intphys2_export.MP4_ERROR
    errors = []
    for concept in specs.CONCEPTS:
        concept_root = out / concept
        with (concept_root / "Main" / "metadata.csv").open() as stream:
            assert tuple(csv.DictReader(stream).fieldnames or ()) == intphys2.METADATA_COLUMNS
        pairs = intphys2.pair_videos(intphys2.read_metadata(concept_root, "Main"))
        scenes = intphys2.SceneDataset(pairs, ClipSampling(SAMPLING), False, SkipLog())
        expected = manifest_pairs(manifest, concept)
        read = []
        for scene in range(len(scenes)):
            scene_records, table = scenes[scene]  # the pairing table by the pair's half
            halves = [intphys2.VARIANT_NAMES[int(record["variant"])] for record in scene_records]
            read += [(scene, record, table[half]) for record, half in zip(scene_records, halves)]
        assert len(read) == len(expected) == sum(key[0] == concept for key in records)
        for (scene, record, entry), (group, pair, half) in zip(read, expected):
            # the same pair, labelled alike, in the same quadruplet and half
            assert f"{concept}/Main/Videos/{entry['possible']}.mp4" == pair["consistent"]
            assert f"{concept}/Main/Videos/{entry['impossible']}.mp4" == pair["inconsistent"]
            assert (scene, int(record["seed"]), int(record["variant"])) == (group["scene"],) * 2 + (
                half,
            )
            principle = intphys2.PRINCIPLES[int(record["concept"])]
            assert principle == intphys2.CONDITIONS[intphys2_export.CONDITIONS[concept]]
            original = store_pair(records, concept, pair)
            for role in ("consistent", "inconsistent"):
                decoded = record[role, "frames"].numpy().astype(int)
                error = np.abs(decoded - original[role, "frames"].numpy().astype(int))
                assert (
                    error.mean() <= bound["mean_absolute"] and error.max() <= bound["max_absolute"]
                )
                errors.append(error.mean())
            # the identical prefix decodes identically: the divergence is the store's own
            m = int(original["manipulation_frame"])
            assert (
                record["consistent", "frames"][: m + 1] == record["inconsistent", "frames"][: m + 1]
            ).all()
            assert int(record["manipulation_frame"]) == first_divergence(
                original["consistent", "frames"].numpy(), original["inconsistent", "frames"].numpy()
            )
    assert 0.2 < np.mean(errors) <= bound["mean_absolute"]  # lossy, within the stated bound


def test_the_surprise_harness_reading_rules_get_every_video_back_exactly(exports, records):
    """The V-JEPA intuitive-physics harness's IntPhys 2 reader, by its rules (facts, not its
    code): the unique ``filename``s of ``labels.csv``, sorted, each a folder under ``Images/``
    that exists; its frames the folder's files in sorted order, every ``frame_step``-th, RGBA's
    alpha dropped. Every video of the export is there, its frames the store's exactly."""
    out, manifest = exports["intphys2"]
    for concept in specs.CONCEPTS:
        main = out / concept / "Main"
        with (main / "labels.csv").open() as stream:
            labels = list(csv.DictReader(stream))
        names = sorted({row["filename"] for row in labels})
        folders = sorted(main / "Images" / name for name in names)
        assert all(folder.is_dir() for folder in folders)
        expected = manifest_pairs(manifest, concept)
        assert len(names) == 2 * len(expected)
        by_name = {row["filename"]: row for row in labels}
        for _, pair, _ in expected:
            original = store_pair(records, concept, pair)
            for role, column in (("consistent", "possible"), ("inconsistent", "impossible")):
                name = pair[role].rpartition("/")[2].removesuffix(".mp4")
                assert by_name[name]["type"].endswith(
                    "Possible" if column == "possible" else "Impossible"
                )
                files = sorted(os.listdir(main / "Images" / name))
                for frame_step in (1, 2):
                    read = np.stack(
                        [
                            np.array(Image.open(main / "Images" / name / f))[..., :3]
                            for f in files[::frame_step]
                        ]
                    )
                    assert np.array_equal(read, original[role, "frames"].numpy()[::frame_step])


#: ComputeScoreIntPhys2.ipynb's property settings (its ``subsplit``): the ``condition`` values
#: each selects; its camera settings select IntPhys 2's own games by ``game_name``.
NOTEBOOK_PROPERTIES = {
    "Permanence": {"permanence"},
    "Immutability": {"immutability", "immutability_texture"},
    "Continuity": {"continuity", "continuity_swap"},
    "Solidity": {"solidity"},
}
NOTEBOOK_CAMERA_GAMES = {
    "FixedMarryPoppins", "FixedJumpSolidity", "RotatingCup", "HotAirBallon",
    "SphereFallingDown", "SolidityFallingFlat", "SphereFallingDownSoldity", "BoxSoldity",
    "Scaffoling", "CameraSolidity", "JumpSolidity", "Box", "MovingAroundOccluder", "JailStone",
    "PrisonCell", "Restaurant",
}  # fmt: skip


def test_the_score_notebooks_rules_score_each_root_by_its_property(exports):
    """ComputeScoreIntPhys2.ipynb's rules (facts, not its code) on each concept's root: its
    ``metadata.csv`` renamed ``name`` -> ``filename`` merges one-to-one with predictions named
    by ``filename``; every ``type`` parses (``Impossible`` before ``Possible``); the root's one
    property setting (docs/benchmarks.md) selects every video, the others none, and its camera
    setting ``All`` every video (its other two name IntPhys 2's games, none of ours)."""
    out, _ = exports["intphys2"]
    for concept in specs.CONCEPTS:
        with (out / concept / "Main" / "metadata.csv").open() as stream:
            rows = [{**row, "filename": row.pop("name")} for row in csv.DictReader(stream)]
        names = [row["filename"] for row in rows]
        assert len(set(names)) == len(names) and rows
        assert {0 if "Impossible" in row["type"] else 1 for row in rows} == {0, 1}
        assert not {row["game_name"] for row in rows} & NOTEBOOK_CAMERA_GAMES
        chosen = intphys2.CONDITIONS[intphys2_export.CONDITIONS[concept]]  # its principle
        for prop, conditions in NOTEBOOK_PROPERTIES.items():
            selected = [row for row in rows if row["condition"] in conditions]
            assert len(selected) == (len(rows) if prop == chosen else 0), (concept, prop)


def test_intphys_reader_reads_the_pairs_labels_quadruplets_and_frames_back_exactly(
    exports, records
):
    out, manifest = exports["intphys"]
    for concept in specs.CONCEPTS:
        block = intphys_export.BLOCKS[concept]
        quadruplets = intphys.scan_quadruplets(out / concept, "dev", FRAMES, labelled=True)
        dataset = intphys.QuadrupletDataset(quadruplets, SAMPLING, False, SkipLog())
        expected = [q for q in manifest["quadruplets"] if q["concept"] == concept]
        assert len(dataset) == len(expected) == PAIRS * len(specs.QUADRUPLETS[concept])
        for index, (group, quadruplet) in enumerate(zip(expected, quadruplets)):
            assert f"{concept}/dev/{quadruplet.scene}" == group["scene"]
            labels = {f"{concept}/dev/{m.name}": m.is_possible for m in quadruplet.movies}
            assert labels == dict.fromkeys(group["consistent"], True) | dict.fromkeys(
                group["inconsistent"], False
            )
            read, entry = dataset[index]
            assert not entry["ambiguous_pairing"]
            for half, (record, pairing, pair) in enumerate(
                zip(read, entry["pairs"], group["pairs"])
            ):
                assert f"{concept}/dev/{pairing['possible']}" == pair["consistent"]
                assert f"{concept}/dev/{pairing['impossible']}" == pair["inconsistent"]
                assert (int(record["seed"]), int(record["variant"])) == (index, half)
                assert intphys.BLOCKS[int(record["concept"])] == block
                original = store_pair(records, concept, {**pair, "seed": group["seed"]})
                for role in ("consistent", "inconsistent"):
                    assert (record[role, "frames"] == original[role, "frames"]).all()
                    masks = np.stack([
                        intphys.read_png(out / pair[role] / "masks" / f"masks_{t:03d}.png")[..., 0]
                        for t in range(1, FRAMES + 1)
                    ])  # fmt: skip
                    assert (masks == original[role, "mask"].numpy()).all()
                assert int(record["manipulation_frame"]) > int(original["manipulation_frame"])


def test_the_intphys_roots_merge_into_one_dev_tree_without_a_clash(exports, tmp_path):
    """Object persistence and solidity are both block O1 (and continuity and containment O3):
    scenes are numbered across the concepts, so a harness given one dev/ tree of every root
    reads every quadruplet once."""
    out, manifest = exports["intphys"]
    merged = tmp_path / "merged" / "dev"
    for concept in specs.CONCEPTS:
        for scene in sorted((out / concept / "dev").glob("O*/*")):
            target = merged / scene.parent.name / scene.name
            assert not target.exists(), f"{concept} writes {target.relative_to(merged)} again"
            target.parent.mkdir(parents=True, exist_ok=True)
            target.symlink_to(scene, target_is_directory=True)
    quadruplets = intphys.scan_quadruplets(merged.parent, "dev", FRAMES, labelled=True)
    assert len(quadruplets) == len(manifest["quadruplets"])
    assert len({q.scene for q in quadruplets}) == len(quadruplets)


def test_read_webdataset_gives_back_every_record_whole(exports, records):
    out, manifest = exports["webdataset"]
    shards = sorted(out.glob("*.tar"))
    assert [shard.name for shard in shards] == ["test-000000.tar"]
    with tarfile.open(shards[0]) as tar:  # the convention: <key>.<ext>, a sample's files together
        keys = [member.name.partition(".")[0] for member in tar]
    assert keys == sorted(keys, key=list(dict.fromkeys(keys)).index)
    samples = list(read_webdataset(shards))
    assert len(samples) == len(records)
    locations = {}
    for group in manifest["quadruplets"] + manifest["pairs"]:
        for half, pair in enumerate(group["pairs"]):
            locations[(group["concept"], pair["variant"], group["seed"])] = (group, pair, half)
    for meta, record in samples:
        original = records[(meta["concept"], meta["variant"], meta["seed"])]
        assert set(record.keys(True, True)) == set(original.keys(True, True))
        assert (record == original).all()
        group, pair, half = locations[(meta["concept"], meta["variant"], meta["seed"])]
        assert pair["consistent"] == f"test-000000.tar/{meta['key']}.consistent"
        assert (meta["quadruplet"], meta["half"]) == (
            group.get("quadruplet"),
            half if "quadruplet" in group else None,
        )
        assert meta["labels"] == {"consistent": "possible", "inconsistent": "impossible"}


def test_one_store_gives_byte_identical_exports(exports, root, tmp_path):
    for export_format, (out, manifest) in exports.items():
        again = export(root, export_format, tmp_path / export_format, progress=False)
        assert again == manifest  # every file's SHA-256 among them
        assert (tmp_path / export_format / MANIFEST_NAME).read_bytes() == (
            out / MANIFEST_NAME
        ).read_bytes()


def test_webdataset_shards_hold_whole_quadruplets(root, tmp_path):
    manifest = export(root, "webdataset", tmp_path / "wd", shard_size=3, progress=False)
    shards = sorted((tmp_path / "wd").glob("*.tar"))
    assert len(shards) > 1 and [s.name for s in shards][:2] == [
        "test-000000.tar",
        "test-000001.tar",
    ]
    for quadruplet in manifest["quadruplets"]:
        assert (
            len(
                {
                    Path(where).parent
                    for where in quadruplet["consistent"] + quadruplet["inconsistent"]
                }
            )
            == 1
        )
    assert sum(1 for _ in read_webdataset(shards)) == sum(
        len(g["pairs"]) for g in manifest["quadruplets"] + manifest["pairs"]
    )


@pytest.mark.slow
def test_the_mp4_error_bound_holds_for_every_rgb_colour():
    """One 4096x4096 frame holds each of the 2^24 colours once (about 10 s)."""
    import av

    colours = np.arange(1 << 24, dtype=np.uint32)
    image = np.stack([colours >> 16, (colours >> 8) & 255, colours & 255], axis=-1)
    image = image.astype(np.uint8).reshape(4096, 4096, 3)
    data = intphys2_export.encode_mp4(
        image[None], intphys2_export.frame_rate({"num_frames": 5, "duration": 1})
    )
    with av.open(io.BytesIO(data)) as container:
        decoded = next(container.decode(video=0)).to_ndarray(format="rgb24")
    error = np.abs(decoded.astype(np.int16) - image)
    assert error.max() == intphys2_export.MP4_ERROR["max_absolute"]
    assert error.mean() < intphys2_export.MP4_ERROR["mean_absolute"]
