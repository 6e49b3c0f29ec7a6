"""The library never depends on the DataModules: no module of ``voe_lightning`` imports
``datamodules``, not even by name in a string (``importlib``, a dispatch table)."""

import ast
import pkgutil
import re
from pathlib import Path

import voe_lightning

NAMES_DATAMODULES = re.compile(r"^datamodules(\.|$)")


def module_files() -> dict[str, Path]:
    """Every module of the package, by name, found without importing it."""
    files = {"voe_lightning": Path(voe_lightning.__file__)}
    for info in pkgutil.walk_packages(voe_lightning.__path__, "voe_lightning."):
        spec = info.module_finder.find_spec(info.name)
        files[info.name] = Path(spec.origin)
    return files


def datamodules_references(path: Path) -> list[str]:
    """Each import of, or string naming, ``datamodules`` in the module at ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            names = [node.module or ""] if node.level == 0 else []
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            names = [node.value]
        else:
            continue
        found += [f"line {node.lineno}: {name!r}" for name in names if NAMES_DATAMODULES.match(name)]
    return found


def test_no_module_of_voe_lightning_imports_datamodules():
    files = module_files()
    assert {"voe_lightning.cli", "voe_lightning.benchmarks.intphys", "voe_lightning.model.base"} <= files.keys()
    offenders = {name: refs for name, path in files.items() if (refs := datamodules_references(path))}
    assert offenders == {}
