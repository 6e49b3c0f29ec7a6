"""Issue 73: a seed offset below a store's pairs per variant is refused (its "fresh" probes
would be the store's own); ``export --seed_offset N`` exports only a store drawn at offset N,
and its advice for a missing one draws exactly that store; an export's staging folder is its
process's own, removed on SIGTERM and after a killed export, and a bad ``--out`` is refused
before any work."""

import os
import shlex
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import refused
from helpers.stores import fake_clip, fake_probe

from voe_lightning.cli import main
from voe_lightning.data import store
from voe_lightning.data.store import render
from voe_lightning.datamodules import ConceptDataModule
from voe_lightning.export import command
from voe_lightning.export.manifest import staged

#: A continuity store of fake renders: 3 test pairs per variant, 16 x 16, 4 frames.
SIZES = ["--concepts", "[continuity]", "--train_examples", "0", "--val_pairs", "1",
         "--test_pairs", "3", "--generalization_pairs", "0", "--num_frames", "8",
         "--height", "16", "--width", "16", "--workers", "1", "--progress", "false"]  # fmt: skip
TEST_START = store.SEED_STARTS["test"]


@pytest.fixture
def root(tmp_path, monkeypatch):
    """A root store (SIZES) of fake renders; later ``generate`` calls render fakes too."""
    monkeypatch.setattr(render, "generate_clip", fake_clip)
    monkeypatch.setattr(render, "generate_probe", fake_probe)
    main(["generate", "--root", str(tmp_path / "data"), *SIZES])
    return tmp_path / "data"


def _seeds(root: Path, split: str = "test") -> set[int]:
    return {int(record["seed"]) for record in store.open_split(root, "continuity", split)}


def test_an_offset_below_the_pairs_per_variant_is_refused_as_no_fresh_set(root, capsys):
    """Case 6: offset 1 with 3 test pairs would redraw seeds 2e9+1 and 2e9+2."""
    assert _seeds(root) == {TEST_START + k for k in range(3)}  # default seeds unchanged
    line = refused(capsys, ["generate", "--root", str(root), *SIZES, "--seed_offset", "1"])
    assert "seed_offset 1 would draw probes already drawn" in line
    assert "give a seed_offset of at least 3" in line
    assert not (root / "seed_offset_1").exists()  # refused before any work
    options = dict(concept="continuity", root=str(root), val_pairs=1, test_pairs=3)
    with pytest.raises(ValueError, match="seed_offset 1 would draw probes already drawn"):
        ConceptDataModule(**options, generalization_pairs=0, seed_offset=1)
    ConceptDataModule(**options, seed_offset=1_000_000)  # the docs' offsets stay valid
    main(["generate", "--root", str(root), *SIZES, "--seed_offset", "3"])
    fresh = _seeds(root / "seed_offset_3")
    assert fresh == {TEST_START + 3 + k for k in range(3)} and not fresh & _seeds(root)


def test_export_of_an_offset_takes_only_that_offsets_store_and_advises_drawing_it(
    root, tmp_path, capsys
):
    """Case 8: the advice for a missing offset store draws the root's probes at that offset
    (concept, pairs, size), and a store of another offset in its place is refused."""
    words = ["export", "--root", str(root), "--format", "webdataset", "--progress", "false"]
    line = refused(capsys, [*words, "--out", str(tmp_path / "a"), "--seed_offset", "7"])
    advice = shlex.split(line.split("`")[1])
    assert advice[:4] == ["python", "-m", "voe_lightning", "generate"]
    assert " ".join(advice[4:]) == (
        f"--root {root} --seed_offset 7 --train_examples 0 --concepts [continuity] "
        "--val_pairs 0 --test_pairs 3 --generalization_pairs 0 --num_frames 8 --height 16 "
        "--width 16"
    )
    main([*advice[3:], "--workers", "1", "--progress", "false"])
    written = main([*words, "--out", str(tmp_path / "a"), "--seed_offset", "7"])
    assert written["seed_offset"] == 7 and written["video"]["height"] == 16
    assert [q["seed"] for q in written["quadruplets"]] == [TEST_START + 7 + k for k in range(3)]
    # What the old advice made: a store at offset 0 in the offset's folder.
    main(["generate", "--root", str(root / "seed_offset_9"), *SIZES])
    line = refused(capsys, [*words, "--out", str(tmp_path / "b"), "--seed_offset", "9"])
    assert "holds probes drawn at seed offset 0, not the 9 asked for" in line
    assert f"generate --root {root} --seed_offset 9 " in line and line.endswith("--overwrite`")
    assert not (tmp_path / "b").exists()
    line = refused(capsys, [*words, "--out", str(tmp_path / "c"), "--seed_offset", "2"])
    assert "give a seed_offset of at least 3" in line  # it would redraw the root's probes
    line = refused(
        capsys, [*words[:2], str(root / "seed_offset_5"), *words[3:], "--out", str(tmp_path / "d")]
    )
    assert f"`python -m voe_lightning generate --root {root} --seed_offset 5 " in line


def test_a_bad_out_is_refused_before_any_work_and_stagings_are_each_exports_own(
    root, tmp_path, capsys, monkeypatch
):
    """An --out that is a symbolic link or under a file is named before anything is read;
    two exports to one out stage apart; a killed export's staging goes on the next export."""

    def write(*_):
        raise AssertionError("the export ran before --out was checked")

    monkeypatch.setattr(command, "writer", lambda *_: write)
    words = ["export", "--root", str(root), "--format", "intphys2", "--progress", "false"]
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    line = refused(capsys, [*words, "--out", str(tmp_path / "link")])
    assert f"--out {tmp_path / 'link'} is a symbolic link" in line
    (tmp_path / "paper.tex").write_text("mine")
    line = refused(capsys, [*words, "--out", str(tmp_path / "paper.tex" / "x")])
    assert f"lies under {tmp_path / 'paper.tex'}, a file" in line
    out = tmp_path / "out"
    with pytest.raises(FileExistsError, match="exists and is not empty"):
        with staged(out) as first:
            with staged(out) as second:
                assert first.path != second.path and first.path.is_dir()
                second.write("x", b"second")
            first.write("x", b"first")  # still there: the second export left it alone
    assert (out / "x").read_bytes() == b"second" and not list(tmp_path.glob(".out.*"))
    dead = subprocess.Popen(["true"])
    dead.wait()
    host = socket.gethostname()
    killed = tmp_path / f".other.{host}.{dead.pid}.abc.partial"
    running = tmp_path / f".other.{host}.{os.getpid()}.abc.partial"
    killed.mkdir(), running.mkdir()
    with staged(tmp_path / "new"):
        pass
    assert not killed.exists() and running.is_dir()


SIGTERM_EXPORT = """
import os, signal, sys, time
from voe_lightning.cli import main
from voe_lightning.export import command

def write(source, folder, bar):
    folder.write("half.bin", b"x")
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(30)

command.writer = lambda *_: write
main(["export", "--root", sys.argv[1], "--format", "webdataset", "--out", sys.argv[2],
      "--progress", "false"])
"""


@pytest.mark.slow
def test_sigterm_during_an_export_removes_its_staging_and_says_so(root, tmp_path):
    out = tmp_path / "exports" / "out"
    done = subprocess.run(
        [sys.executable, "-c", SIGTERM_EXPORT, str(root), str(out)],
        capture_output=True, text=True, timeout=120,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )  # fmt: skip
    assert done.returncode == 128 + signal.SIGTERM, done.stderr
    assert f"export stopped by SIGTERM; nothing written to {out}" in done.stderr
    assert list(out.parent.iterdir()) == []
