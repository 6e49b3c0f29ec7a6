"""Writing files whole: each is staged in a temporary file beside it, fsynced, and renamed over
the old one, several as a set (``write_whole``), so a write that fails (a full disk, a kill)
leaves every previous file whole. The store writes its shards and manifest so, and the rest of
the package every file it keeps (reports, predictions, checkpoints). What a killed writer staged
is removed by the next write there (``remove_stale``)."""

from __future__ import annotations

import glob
import os
import re
import shutil
import socket
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO, TypeVar

from voe_lightning.data.store.errors import CorruptShardError

#: A file's name as ``write_whole`` takes it (a Mapping's key type is invariant: any one kind).
_FileName = TypeVar("_FileName", bound="str | os.PathLike[str]")


def atomic_write(path: str | os.PathLike[str], chunks: Iterable[bytes]) -> int:
    """Write ``chunks`` to ``path`` atomically (temporary file in the same folder, fsync,
    rename); returns the bytes written. The file gets the mode ``open`` would give it (0666
    less the umask; ``mkstemp`` alone makes it 0600, unreadable to a lab's other users).
    OSErrors (no space, no permission) name ``path``."""
    return write_whole({path: chunks})[Path(path)]


def write_whole(
    files: Mapping[_FileName, Iterable[bytes] | bytes | str],
) -> dict[Path, int]:
    """Write several files as ``atomic_write`` does one, as a set: every file is staged (its
    temporary file in its own folder, written and fsynced) before any replaces its old
    version, so a write that fails (a full disk) leaves every previous file whole, and the
    error names the file. An empty folder where a file belongs is replaced too (a non-empty
    one is named). Contents are bytes, text (UTF-8) or chunks of bytes; returns the bytes
    written per file."""
    staged: dict[Path, str] = {}
    sizes: dict[Path, int] = {}
    try:
        for name, content in files.items():
            path = Path(name)
            chunks = (
                [content.encode()]
                if isinstance(content, str)
                else [content]
                if isinstance(content, bytes)
                else content
            )
            staged[path], sizes[path] = _stage(path, chunks)
        for path in list(staged):
            try:
                if path.is_dir() and not path.is_symlink() and not any(path.iterdir()):
                    path.rmdir()
                os.replace(staged[path], path)
            except OSError as error:
                raise OSError(
                    error.errno, f"cannot write {path}: {error.strerror or error}", str(path)
                ) from error
            del staged[path]
        return sizes
    finally:
        for temporary in staged.values():
            try:
                os.unlink(temporary)
            except OSError:
                pass


def _stage(path: Path, chunks: Iterable[bytes]) -> tuple[str, int]:
    """``chunks`` written and fsynced to a new temporary file beside ``path`` (with ``open``'s
    mode): its name and size. OSErrors name ``path``; the temporary file is gone after one,
    and those a killed writer left beside ``path`` go first (``remove_stale``)."""
    temporary = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale(path.parent, path.name)
        handle, temporary = tempfile.mkstemp(
            prefix=temporary_prefix(path.name), suffix=".tmp", dir=path.parent
        )
        os.fchmod(handle, 0o666 & ~current_umask())
        size = 0
        with os.fdopen(handle, "wb") as file:
            for chunk in chunks:
                _write_bytes(file, chunk)
                size += len(chunk)
            file.flush()
            os.fsync(file.fileno())
        return temporary, size
    except OSError as error:
        if temporary is not None:
            try:
                os.unlink(temporary)
            except OSError:
                pass
        if isinstance(error, CorruptShardError):
            raise
        reason = error.strerror or str(error)
        raise OSError(error.errno, f"cannot write {path}: {reason}", str(path)) from error


def _write_bytes(file: IO[bytes], data: bytes) -> None:
    file.write(data)


def current_umask() -> int:
    """This process's umask, read without changing it (``os.umask`` would, for every thread)."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def temporary_prefix(name: str) -> str:
    """``.<name>.<host>.<pid>.``: the prefix of a temporary file or folder of this process
    standing in for ``name`` (``remove_stale`` tells those of a killed process)."""
    return f".{name}.{socket.gethostname()}.{os.getpid()}."


def remove_stale(folder: Path, name: str) -> None:
    """Remove the temporary files and folders (``temporary_prefix``) of ``name`` in ``folder``
    that a process of this host left when it was killed (SIGKILL, power loss) before cleaning
    up: its id no longer runs. Another host's, or a running process's, are left alone."""
    pattern = re.compile(rf"\.{re.escape(name)}\.{re.escape(socket.gethostname())}\.(\d+)\.")
    for path in folder.glob(f".{glob.escape(name)}.*"):
        match = pattern.match(path.name)
        if match and not _running(int(match[1])):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)


def _running(pid: int) -> bool:
    """Whether a process ``pid`` runs on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's
        return True
    return True
