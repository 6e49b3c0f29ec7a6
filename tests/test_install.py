"""scripts/install.sh on a Python that cannot install packages: it stops saying what to do."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.locations import REPO

INSTALL = REPO / "scripts" / "install.sh"


def run_with_python3(shim: str, tmp_path: Path) -> subprocess.CompletedProcess:
    """install.sh with ``python3`` on PATH replaced by the bash script ``shim``."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    python3 = bin_dir / "python3"
    python3.write_text(f"#!/usr/bin/env bash\nREAL={sys.executable}\n{shim}\n")
    python3.chmod(python3.stat().st_mode | stat.S_IXUSR)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}
    return subprocess.run(
        ["bash", str(INSTALL)], env=env, capture_output=True, text=True, timeout=120
    )


@pytest.mark.skipif(sys.platform != "linux", reason="install.sh is for Debian/Ubuntu")
def test_a_python_without_pip_is_named_with_the_fix(tmp_path):
    shim = 'if [ "$1 $2" = "-m pip" ]; then echo "No module named pip" >&2; exit 1; fi\nexec "$REAL" "$@"'
    result = run_with_python3(shim, tmp_path)
    assert result.returncode == 1, result.stderr
    assert "has no pip" in result.stderr and "python3 -m venv .venv" in result.stderr
    assert str(tmp_path / "bin" / "python3") in result.stderr


@pytest.mark.skipif(sys.platform != "linux", reason="install.sh is for Debian/Ubuntu")
def test_pips_refusal_of_a_system_managed_python_comes_with_the_fix(tmp_path):
    """A Python marked EXTERNALLY-MANAGED (PEP 668) makes `pip install` fail with pip's
    'externally-managed-environment' error (here from the shim, which stands in for pip)."""
    refusal = "error: externally-managed-environment"
    shim = f'if [ "$3" = "install" ]; then echo "{refusal}" >&2; exit 1; fi\nexec "$REAL" "$@"'
    result = run_with_python3(shim, tmp_path)
    assert result.returncode == 1, result.stderr
    assert refusal in result.stderr  # pip's own message is kept
    assert "managed by the system (PEP 668)" in result.stderr
    assert "python3 -m venv .venv" in result.stderr
