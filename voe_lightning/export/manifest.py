"""What every export carries and how it is written: the folder it is staged in (renamed into
place only once whole), the SHA-256 of each file written, and ``manifest.json``, which says what
the export holds so a paper can cite it ("voe_lightning probes v10, test split, seed offset
K"): generator and package versions, store, split, seeds, seed offset, video geometry, how
frames were encoded, each concept's place in the benchmark's layout, the quadruplet grouping
(which four videos, which consistent, which inconsistent, which concept) and the lone pairs."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import signal
import socket
import sys
import tempfile
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from tensordict import TensorDictBase

import voe_lightning
from voe_lightning.data import store
from voe_lightning.data.store import (
    GENERATOR_VERSION,
    current_umask,
    remove_stale,
    temporary_prefix,
)
from voe_lightning.export.probes import ROLES, ProbeGroup, ProbeSource

MANIFEST_NAME = "manifest.json"
#: How the name of the hidden folder an export is staged in ends (``staged``).
PARTIAL = ".partial"
#: Version of the export layouts and of this manifest; bump it when either changes.
EXPORT_VERSION = 1


def sha256_file(path: Path) -> str:
    """The SHA-256 of the file at ``path``, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for chunk in iter(lambda: stream.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


class ExportFolder:
    """The folder an export is written into, keeping the SHA-256 of every file written
    (``files``: path relative to the folder, with ``/`` -> hex digest) for the manifest."""

    def __init__(self, path: Path):
        self.path = path
        self.files: dict[str, str] = {}

    def write(self, relative: str, data: bytes) -> None:
        """Write ``data`` to ``relative`` (folders made as needed) and note its SHA-256."""
        path = self.path / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        self.files[relative] = hashlib.sha256(data).hexdigest()

    def add(self, relative: str) -> None:
        """Note the SHA-256 of ``relative``, a file written otherwise (a tar shard)."""
        self.files[relative] = sha256_file(self.path / relative)


@dataclass
class Written:
    """What a format's writer reports for the manifest: where each concept went (``layout``),
    how frames were encoded, each group's entry (``group_entry``) and what it left out."""

    layout: dict[str, Any]
    encoding: dict[str, Any]
    groups: list[dict[str, Any]] = field(default_factory=list)
    left_out: list[dict[str, Any]] = field(default_factory=list)


class Progress(Protocol):
    """The part of a tqdm bar a writer uses: ``update(videos written)``."""

    def update(self, n: float | None = 1) -> bool | None: ...


def check_out(out: Path) -> None:
    """Refuse an ``out`` that is a symbolic link or lies under a file (the finished export is
    renamed into place, which neither allows), is a file, or is a folder that is not empty:
    an export never writes over or beside other files. Checked before any work, and again
    before the rename."""
    if out.is_symlink():
        raise FileExistsError(
            f"--out {out} is a symbolic link (to {os.readlink(out)}); give the folder's own "
            f"path, e.g. {out.resolve()}"
        )
    above = next((path for path in out.parents if path.exists() and not path.is_dir()), None)
    if above is not None:
        raise NotADirectoryError(f"--out {out} lies under {above}, a file; give a folder's path")
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out} is a file; give a new or empty folder")
    if out.is_dir() and any(out.iterdir()):
        raise FileExistsError(
            f"--out {out} exists and is not empty; give a new or empty folder (an export "
            "never writes over or beside other files)"
        )


@contextlib.contextmanager
def staged(out: Path) -> Iterator[ExportFolder]:
    """An ExportFolder in a hidden folder of this process beside ``out``
    (``.<out>.<host>.<pid>.*.partial``), renamed to ``out`` when the block ends without error
    and deleted when it raises or SIGTERM stops it: an interrupted export leaves no ``out``
    that looks whole, two exports to one ``out`` never share one, and the ones a killed
    export left (SIGKILL) beside any ``out`` go first (``remove_stale_partials``)."""
    check_out(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_partials(out.parent)
    with _sigterm_stops(out):
        partial = Path(
            tempfile.mkdtemp(prefix=temporary_prefix(out.name), suffix=PARTIAL, dir=out.parent)
        )
        try:
            os.chmod(partial, 0o777 & ~current_umask())  # mkdtemp's 0700 hides it from a lab
            yield ExportFolder(partial)
            check_out(out)  # nothing appeared there meanwhile
            if out.is_dir():
                out.rmdir()
            os.rename(partial, out)
        except BaseException:
            shutil.rmtree(partial, ignore_errors=True)
            raise


def remove_stale_partials(folder: Path) -> None:
    """Remove the partial exports (``staged``) in ``folder``, of any ``out``, that an export
    of this host left when it was killed: ``store.remove_stale`` of each ``out``."""
    pattern = rf"\.(.+)\.{re.escape(socket.gethostname())}\.\d+\..*{re.escape(PARTIAL)}"
    for path in folder.glob(f".*{PARTIAL}"):
        match = re.fullmatch(pattern, path.name)
        if match:
            remove_stale(folder, match[1])


@contextlib.contextmanager
def _sigterm_stops(out: Path) -> Iterator[None]:
    """While the block runs (in the main thread), SIGTERM raises SystemExit(128 + SIGTERM),
    saying so, instead of ending the process at once: the partial export is removed on the
    way out. A second SIGTERM is ignored until then, so it cannot cut that short."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, frame: object) -> None:
        signal.signal(signum, signal.SIG_IGN)
        print(f"export stopped by SIGTERM; nothing written to {out}", file=sys.stderr)
        raise SystemExit(128 + signum)

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def pair_entry(variant: str, record: TensorDictBase, locations: Sequence[str]) -> dict[str, Any]:
    """A pair's manifest entry: its variant, manipulation frame and where its consistent and
    inconsistent videos are in the export (``locations``, in ``ROLES`` order)."""
    return {
        "variant": variant,
        "manipulation_frame": int(record["manipulation_frame"]),
        **dict(zip(ROLES, locations)),
    }


def group_entry(
    group: ProbeGroup,
    records: Sequence[TensorDictBase],
    locations: Sequence[Sequence[str]],
    scene: Any = None,
) -> dict[str, Any]:
    """A group's manifest entry: concept, seed, the benchmark's ``scene`` for it, and each
    pair's entry (``locations[k]``: pair k's video locations); a quadruplet's also names its
    row and lists its consistent (A, B) and inconsistent (AB, BA) videos."""
    pairs = [
        pair_entry(pair.variant, record, where)
        for pair, record, where in zip(group.pairs, records, locations)
    ]
    entry: dict[str, Any] = {"concept": group.concept, "seed": group.seed, "scene": scene}
    if group.quadruplet is not None:
        entry["quadruplet"] = group.quadruplet
        entry.update({role: [where[k] for where in locations] for k, role in enumerate(ROLES)})
    return {**entry, "pairs": pairs}


def citation(source: ProbeSource) -> str:
    """How a paper names the exported probes."""
    return (
        f"voe_lightning probes v{GENERATOR_VERSION}, {source.split} split, seed offset "
        f"{source.seed_offset}"
    )


def build_manifest(
    source: ProbeSource, export_format: str, written: Written, files: dict[str, str]
) -> dict[str, Any]:
    """The export's manifest: what it is (``export_format``; from ``written``, the layout:
    where each concept went, and how frames were encoded), what it holds (the quadruplets and
    lone pairs, what was left out and why) and the SHA-256 of each file."""
    video = source.video
    store_manifest = source.root / store.MANIFEST_NAME
    return {
        "citation": citation(source),
        "export_format": export_format,
        "export_version": EXPORT_VERSION,
        "generator_version": GENERATOR_VERSION,
        "package_version": voe_lightning.__version__,
        "store": {
            "root": str(source.root),
            "manifest_sha256": sha256_file(store_manifest),
            "package_version": source.manifest.get("package_version"),
        },
        "split": source.split,
        "seed_offset": source.seed_offset,
        "seeds": {concept: source.seeds(concept) for concept in source.concepts},
        "video": {**video, "fps": video["num_frames"] / video["duration"]},
        "layout": written.layout,
        "encoding": written.encoding,
        "quadruplets": [entry for entry in written.groups if "quadruplet" in entry],
        "pairs": [entry for entry in written.groups if "quadruplet" not in entry],
        "left_out": written.left_out,
        "files": dict(sorted(files.items())),
    }


def write_manifest(folder: ExportFolder, manifest: dict[str, Any]) -> None:
    """Write ``manifest.json`` (not among its own ``files``)."""
    text = json.dumps(manifest, indent=2) + "\n"
    (folder.path / MANIFEST_NAME).write_text(text)
