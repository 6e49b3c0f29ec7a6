"""The library never depends on the DataModules: no module of ``voe_lightning`` imports
``datamodules``, not even by name in a string (``importlib``, a dispatch table); and no module of
the package is in an import circle, not even through an import inside a function or a
package's ``__init__``; and none is over 500 lines."""

import ast
import graphlib
import pkgutil
import re
from pathlib import Path

import voe_lightning
from voe_lightning.old_paths import OLD_PATHS

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
        found += [
            f"line {node.lineno}: {name!r}" for name in names if NAMES_DATAMODULES.match(name)
        ]
    return found


def test_no_module_of_voe_lightning_imports_datamodules():
    files = module_files()
    assert {
        "voe_lightning.cli",
        "voe_lightning.external.intphys",
        "voe_lightning.model.base",
    } <= files.keys()
    offenders = {
        name: refs for name, path in files.items() if (refs := datamodules_references(path))
    }
    assert offenders == {}


def package_imports(name: str, path: Path, modules: set[str]) -> set[str]:
    """The package's modules that the module ``name`` at ``path`` imports, anywhere in it (a
    function's import is a circle too, only a later one): ``from a import b`` names the module
    ``a.b`` when there is one, else ``a``."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            candidates = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            module = ".".join(part for part in (base, node.module) if part)
            candidates = [
                f"{module}.{alias.name}" if f"{module}.{alias.name}" in modules else module
                for alias in node.names
            ]
        else:
            continue
        for candidate in candidates:
            while candidate and candidate not in modules:  # a.b.c of a module a.b: a.b
                candidate = candidate.rpartition(".")[0]
            if candidate and candidate != name:
                found.add(candidate)
                found |= enclosing_packages(candidate, name, modules)
    return found


def enclosing_packages(imported: str, importer: str, modules: set[str]) -> set[str]:
    """The packages whose ``__init__`` importing ``imported`` runs first (``a`` and ``a.b`` for
    ``a.b.c``), less those that enclose ``importer``: they have started already."""
    parts = imported.split(".")
    outer = {".".join(parts[:i]) for i in range(1, len(parts))}
    running = {".".join(importer.split(".")[:i]) for i in range(1, importer.count(".") + 2)}
    return (outer & modules) - running


def test_no_module_of_voe_lightning_is_in_an_import_circle():
    files = module_files()
    graph = {name: package_imports(name, path, set(files)) for name, path in files.items()}
    assert graph["voe_lightning.data.generate"] >= {
        "voe_lightning.data.store",
        "voe_lightning.data.store_plan",
    }
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as error:
        raise AssertionError(f"import circle: {' -> '.join(error.args[1])}") from None


def test_no_module_of_voe_lightning_imports_an_old_module_path():
    """The old flat paths (``voe_lightning.statistics``) are for saved configs and other people's
    code; the package itself imports the modules where they are."""
    files = module_files()
    assert not OLD_PATHS.keys() & files.keys()  # an old path is no file
    offenders = {
        name: old
        for name, path in files.items()
        if (old := package_imports(name, path, set(files) | OLD_PATHS.keys()) & OLD_PATHS.keys())
    }
    assert offenders == {}


def test_no_module_of_voe_lightning_is_over_500_lines():
    """One idea per module: a module past 500 lines holds two (CONTRIBUTING.md)."""
    files = module_files()
    long = {
        name: n for name, path in files.items() if (n := len(path.read_text().splitlines())) > 500
    }
    assert len(files) > 100
    assert long == {}
