"""Installed like any package: a wheel built from the checkout, installed into a fresh virtual
environment outside it (its dependencies from the environment running the test, a virtual
environment or the system's, so nothing is downloaded), runs from an empty folder: a shipped
config by name, and generate, a 2-step fit, test (``--ckpt_path last``) and audit of a config
file there, reading base.yaml from the installed package; ``voe_lightning`` is the only package
it puts into site-packages, and its shipped checkpoints unpack from it."""

import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.locations import REPO, TINY_CONFIG

#: What the wheel is built from.
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "voe_lightning")


@pytest.mark.slow
def test_a_wheel_installed_outside_the_checkout_runs_there(tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(
                REPO / name, source / name, ignore=shutil.ignore_patterns("__pycache__")
            )
        else:
            shutil.copy(REPO / name, source / name)
    wheels, venv, work = tmp_path / "wheels", tmp_path / "venv", tmp_path / "work"
    pip = ["-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([sys.executable, *pip, "wheel", "--no-deps", "--no-build-isolation", "-w", wheels, source], check=True)  # fmt: skip
    (wheel,) = wheels.glob("voe_lightning-*.whl")
    assert wheel.stat().st_size < 20 * 2**20  # the shipped checkpoints inside (issue 72)
    subprocess.run([sys.executable, "-m", "venv", venv], check=True)
    python = str(venv / "bin" / "python")
    _see_the_running_packages(python)
    subprocess.run([python, *pip, "install", "--no-deps", wheel], check=True)
    work.mkdir()
    shutil.copy(TINY_CONFIG, work / "tiny.yaml")
    environment = {**os.environ, "MUJOCO_GL": "egl"}
    environment.pop("PYTHONPATH", None)

    def run(*words: str) -> str:
        done = subprocess.run(
            [python, *words], cwd=work, env=environment, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr[-3000:]
        return done.stdout

    installed = (
        "import importlib.metadata as m; print(*{f.parts[0] for f in m.files('voe_lightning')})"
    )
    tops = {top for top in run("-c", installed).split() if top != ".."}  # ../bin: the scripts
    assert {top for top in tops if not top.endswith(".dist-info")} == {"voe_lightning"}
    where = run("-c", "import voe_lightning.runs as r; print(r.BASE_CONFIG)")
    assert where.strip().startswith(str(venv)) and where.strip().endswith(
        "voe_lightning/configs/base.yaml"
    )
    shipped = run("-c", "import voe_lightning.shipped as s; print(*sorted(s.SHIPPED))").split()
    for name in shipped:  # each file inside the installed package, as recorded
        run("-c", f"import voe_lightning.shipped as s; s.unpack({name!r}, 'runs')")
    assert shipped and len(
        list((work / "runs" / "shipped").glob("*/checkpoints/last.ckpt"))
    ) == len(shipped)
    assert "name: quickstart" in run("-m", "voe_lightning", "fit", "--config", "quickstart", "--print_config")  # fmt: skip
    run("-m", "voe_lightning", "generate", "--root", "data/tiny", "--concepts", "[object_persistence]",
        "--train_examples", "4", "--val_pairs", "2", "--test_pairs", "3", "--generalization_pairs", "2",
        "--num_frames", "8", "--height", "32", "--width", "32", "--workers", "1", "--progress", "false")  # fmt: skip
    assert "next, the report on the test probes" in run("-m", "voe_lightning", "fit", "--config", "tiny.yaml")  # fmt: skip
    run("-m", "voe_lightning", "test", "--config", "tiny.yaml", "--ckpt_path", "last")
    assert (work / "runs" / "tiny" / "version_0" / "voe_report" / "summary.json").is_file()
    run("-m", "voe_lightning", "audit", "--root", "data/tiny", "--split", "test", "--progress", "false")  # fmt: skip
    assert any((work / "data" / "tiny").rglob("cues.md"))


def _see_the_running_packages(python: str) -> None:
    """Put the site-packages this test runs with after the new environment's own, by a ``.pth``
    file: ``--system-site-packages`` would give the base Python's, which in a virtual
    environment (the README's advice under PEP 668) lack the dependencies installed in it."""
    where = subprocess.run(
        [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    user = [site.getusersitepackages()] if site.ENABLE_USER_SITE else []
    running = [path for path in sys.path if path in {*site.getsitepackages(), *user}]
    (Path(where) / "running_site_packages.pth").write_text("\n".join(running) + "\n")
