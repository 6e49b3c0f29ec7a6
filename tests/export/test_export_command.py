"""``python -m voe_lightning export`` on a real one-concept store: the command and its progress
bar, a fresh test set by its seed offset, one-line refusals of bad input (each naming the bad
value and what is valid), and no half-written export when writing fails."""

import json

import pytest
from helpers import refused

from voe_lightning.cli import main
from voe_lightning.data.store import generate_dataset
from voe_lightning.export import command, manifest
from voe_lightning.export.probes import open_probes

OFFSET = 7
SMALL = dict(
    concepts=["continuity"], train_examples=0, val_pairs=1, test_pairs=1, workers=1,
    num_frames=8, height=32, width=32, progress=False,
)  # fmt: skip


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """continuity's test split (one quadruplet and a lone pair), its generalization split (a
    lone pair; the validation split is planned and not generated) and a fresh test set at
    seed offset OFFSET."""
    folder = tmp_path_factory.mktemp("store")
    generate_dataset(folder, generalization_pairs=1, splits=("test", "generalization"), **SMALL)
    generate_dataset(folder, generalization_pairs=0, splits=("test",), seed_offset=OFFSET, **SMALL)
    return folder


def test_the_command_writes_an_export_with_a_progress_bar(root, tmp_path, capsys):
    out = tmp_path / "export"
    written = main(["export", "--root", str(root), "--format", "webdataset", "--out", str(out)])
    captured = capsys.readouterr()
    assert "export webdataset" in captured.err and "video" in captured.err  # tqdm's bar
    assert "1 quadruplets and 1 lone pairs" in captured.out
    assert "cite as: voe_lightning probes v" in captured.out
    assert json.loads((out / manifest.MANIFEST_NAME).read_text()) == written
    assert sorted(path.name for path in out.iterdir()) == ["manifest.json", "test-000000.tar"]


def test_a_seed_offset_exports_the_fresh_test_set(root, tmp_path):
    written = command.export(
        root, "intphys2", tmp_path / "fresh", seed_offset=OFFSET, progress=False
    )
    assert written["seed_offset"] == OFFSET and written["citation"].endswith(
        f"seed offset {OFFSET}"
    )
    assert written["store"]["root"] == str(root / f"seed_offset_{OFFSET}")
    assert written["seeds"]["continuity"]["seed_start"] == 2_000_000_000 + OFFSET
    assert [q["seed"] for q in written["quadruplets"]] == [2_000_000_000 + OFFSET]


def test_an_empty_out_folder_is_used(root, tmp_path):
    (tmp_path / "empty").mkdir()
    command.export(root, "intphys", tmp_path / "empty", progress=False)
    assert (
        tmp_path / "empty" / "continuity" / "dev" / "O3" / "0001" / "4" / "status.json"
    ).is_file()


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["--format", "mpeg"], "unknown format 'mpeg'; valid formats are: intphys2, intphys, webdataset"),
        (["--split", "train"], "split 'train' holds no probe pairs; probe splits are: val, test, generalization"),
        (["--concepts", "[gravity]"], "unknown concept 'gravity'; valid concepts are: object_persistence"),
        (["--concepts", "[solidity]"], "concept 'solidity' was not generated in"),
        (["--shard_size", "0"], "shard_size must be a positive integer, got 0"),
        (["--seed_offset", "-1"], "seed_offset must be an integer in [0, 999_999_999]"),
        (["--seed_offset", "3"], "seed_offset_3/manifest.json is missing"),
        (["--split", "val"], "corrupt shard"),  # planned, never generated
        (["--split", "generalization", "--format", "intphys"], "holds no quadruplets for continuity, and an IntPhys scene is one"),
    ],
)  # fmt: skip
def test_bad_input_is_refused_in_one_line_naming_it(root, tmp_path, capsys, arguments, message):
    words = ["export", "--root", str(root), "--format", "intphys2", "--out", str(tmp_path / "x")]
    line = refused(capsys, words + ["--progress", "false", *arguments])
    assert message in line
    assert not (tmp_path / "x").exists() and not (tmp_path / ".x.partial").exists()


def test_a_root_that_is_no_store_and_a_full_out_folder_are_refused(root, tmp_path, capsys):
    words = ["export", "--format", "intphys", "--progress", "false"]
    line = refused(capsys, words + ["--root", str(tmp_path), "--out", str(tmp_path / "x")])
    assert f"no dataset at {tmp_path}" in line and "generate --root" in line
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "paper.tex").write_text("mine")
    line = refused(capsys, words + ["--root", str(root), "--out", str(tmp_path / "full")])
    assert f"--out {tmp_path / 'full'} exists and is not empty" in line
    assert [path.name for path in (tmp_path / "full").iterdir()] == ["paper.tex"]


def test_a_failed_export_leaves_nothing_behind(root, tmp_path, monkeypatch):
    def failing(source, folder, bar):
        folder.write("continuity/dev/O3/0001/1/status.json", b"{}")
        raise OSError("No space left on device")

    monkeypatch.setattr(command, "writer", lambda *_: failing)
    with pytest.raises(OSError, match="No space left"):
        command.export(root, "intphys", tmp_path / "out", progress=False)
    assert list(tmp_path.iterdir()) == []


def test_groups_are_quadruplets_then_lone_pairs(root):
    source = open_probes(root, "test")
    assert [(g.quadruplet, [p.variant for p in g.pairs]) for g in source.groups] == [
        ("quadruplet", ["standard", "counterbalanced"]),
        (None, ["paper"]),
    ]
    names = [
        p.video_name(role)
        for g in source.groups
        for p in g.pairs
        for role in ("consistent", "inconsistent")
    ]
    seed = 2_000_000_000
    assert names == [
        f"continuity_{seed}_quadruplet_A", f"continuity_{seed}_quadruplet_AB",
        f"continuity_{seed}_quadruplet_B", f"continuity_{seed}_quadruplet_BA",
        f"continuity_{seed}_paper_consistent", f"continuity_{seed}_paper_inconsistent",
    ]  # fmt: skip
    assert source.num_videos == 6
