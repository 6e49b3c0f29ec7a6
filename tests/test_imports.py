"""The library never depends on the DataModules: no module of ``voe_lightning`` outside
``voe_lightning.datamodules`` imports it, not even by name in a string (``importlib``, a
dispatch table); no module of
the package is in an import circle, not even through an import inside a function or a
package's ``__init__``; none is over 500 lines; each name has one path (no module but a
package's ``__init__`` re-exports a name it imports); the lower layers import no higher one; and
no module of the tests imports a test module."""

import ast
import graphlib
import pkgutil
import re
import sys
from collections.abc import Iterable
from pathlib import Path

from helpers.locations import REPO

import voe_lightning

NAMES_DATAMODULES = re.compile(r"^(voe_lightning\.)?datamodules(\.|$)")


def module_files(package=voe_lightning) -> dict[str, Path]:
    """Every module of ``package``, by name, found without importing it."""
    files = {package.__name__: Path(package.__file__)}
    for info in pkgutil.walk_packages(package.__path__, f"{package.__name__}."):
        spec = info.module_finder.find_spec(info.name)
        files[info.name] = Path(spec.origin)
    return files


def datamodules_references(path: Path) -> list[str]:
    """Each import of, or string naming, the DataModules' package in the module at ``path``."""
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
    files = {  # but migrate, whose table of moved modules names the package's old path and new
        name: path
        for name, path in module_files().items()
        if not NAMES_DATAMODULES.match(name.removeprefix("voe_lightning."))
        and name != "voe_lightning.migration"
    }
    assert {
        "voe_lightning.cli",
        "voe_lightning.benchmarks.intphys.reader",
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
    assert graph["voe_lightning.data.store.generation"] >= {
        "voe_lightning.data.store.plan",
        "voe_lightning.data.store.manifest",
    }
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as error:
        raise AssertionError(f"import circle: {' -> '.join(error.args[1])}") from None


def test_no_module_of_voe_lightning_is_over_500_lines():
    """One idea per module: a module past 500 lines holds two (CONTRIBUTING.md)."""
    files = module_files()
    long = {
        name: n for name, path in files.items() if (n := len(path.read_text().splitlines())) > 500
    }
    assert len(files) > 100
    assert long == {}


def test_the_command_line_is_at_most_1200_lines():
    """``cli/`` parses, checks and dispatches (issue 71): analyses and checks of a topic live
    in their own packages, so the whole command line stays under 1,200 lines."""
    lines = sum(len(p.read_text().splitlines()) for p in (REPO / "voe_lightning/cli").glob("*.py"))
    assert lines <= 1200, f"voe_lightning/cli/ is {lines} lines"


#: The lower layers, lowest first: a module of one imports only modules of its own layer or of
#: the layers before it (the package's ``__init__`` sets the environment only). Everything else
#: (``model``, ``callbacks``, ``report``, ``audit``, ``benchmarks``, ``cli``, the root's other
#: modules) is higher and may import them.
LAYERS = (
    ("voe_lightning", "voe_lightning.specs"),
    ("voe_lightning.stats", "voe_lightning.scenes"),
    ("voe_lightning.data",),
)


def layer(name: str) -> int:
    """The index in ``LAYERS`` of module ``name``'s layer; ``len(LAYERS)`` for a higher one."""
    for index, prefixes in enumerate(LAYERS):
        if any(name == p or (p != "voe_lightning" and name.startswith(f"{p}.")) for p in prefixes):
            return index
    return len(LAYERS)


def test_no_module_of_a_lower_layer_imports_a_higher_one():
    files = module_files()
    assert (
        layer("voe_lightning.stats.verdicts") == 1 and layer("voe_lightning.model.causality") == 3
    )
    climbs = {
        f"{name} -> {imported}"
        for name, path in files.items()
        if layer(name) < len(LAYERS)
        for imported in package_imports(name, path, set(files))
        if layer(imported) > layer(name)
    }
    assert climbs == set()


def defined_names(path: Path) -> set[str]:
    """The names a module's own top-level code binds (functions, classes, assignments, also
    under a top-level ``if`` or ``try``), not those it imports."""
    names, todo = set(), list(ast.parse(path.read_text(), str(path)).body)
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
        elif isinstance(node, (ast.If, ast.Try)):
            todo += node.body + node.orelse + getattr(node, "finalbody", [])
            todo += [line for handler in getattr(node, "handlers", []) for line in handler.body]
    return names


def exported_names(path: Path) -> list[str]:
    """The names of a module's ``__all__``, if it has one."""
    for node in ast.parse(path.read_text(), str(path)).body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets
        ):
            return list(ast.literal_eval(node.value))
    return []


def imported_names(path: Path, modules: Iterable[str]) -> list[tuple[str, str, int]]:
    """Each name the file at ``path`` takes from one of ``modules`` (absolute imports only):
    ``from module import name``, or ``module.name`` where ``from package import module`` or
    ``import module as alias`` named it; as the module, the name and the line."""
    tree = ast.parse(path.read_text(), str(path))
    found, aliases = [], {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            for alias in node.names:
                if f"{node.module}.{alias.name}" in modules:
                    aliases[alias.asname or alias.name] = f"{node.module}.{alias.name}"
                else:
                    found.append((node.module, alias.name, node.lineno))
        elif isinstance(node, ast.Import):
            aliases |= {alias.asname: alias.name for alias in node.names if alias.asname}
    return found + [
        (aliases[node.value.id], node.attr, node.lineno)
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.value.id in aliases
        and not node.attr.startswith("__")  # a module's own __name__, __file__, ...
    ]


def test_no_module_re_exports_a_name_it_does_not_define():
    """One path per name: a name is imported from the module that defines it. Only a package's
    ``__init__`` offers names of its modules (its public API); any other module's ``__all__``
    lists only its own names, and nothing imports from it a name it imported itself."""
    files = module_files()
    modules = {name: path for name, path in files.items() if path.name != "__init__.py"}
    defined = {name: defined_names(path) for name, path in modules.items()}
    assert {"check_alpha", "paired_test"} <= defined["voe_lightning.stats.statistics"]
    exported = {f"{name}.{n}" for name, path in modules.items() for n in exported_names(path)}
    offenders = {
        path for path in exported if path.rpartition(".")[2] not in defined[path.rpartition(".")[0]]
    }
    sources = list(files.values()) + [
        path
        for folder in ("tests", "experiments", "benchmarks", "scripts")
        for path in (REPO / folder).rglob("*.py")
    ]
    offenders |= {
        f"{path.relative_to(REPO)}:{line}: {module}.{name}"
        for path in sources
        for module, name, line in imported_names(path, files)
        if module in defined and name not in defined[module]
    }
    assert offenders == set()


def test_importing_the_package_installs_no_import_hook():
    finders = [type(finder).__module__ for finder in sys.meta_path]
    assert not [module for module in finders if module.startswith("voe_lightning")]


def imported_modules(path: Path) -> set[str]:
    """Each module an import anywhere in the file at ``path`` names (a function's too):
    ``import a.b`` names ``a.b``; ``from a import b`` names ``a`` and, ``b`` being maybe a
    module, ``a.b``; ``from . import b``, ``b``."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            module = node.module if node.level == 0 else None
            found |= {module} if module else set()
            found |= {".".join(filter(None, (module, alias.name))) for alias in node.names}
    return found


def test_no_module_of_the_tests_imports_a_test_module():
    """A test module is run, never imported: what several test modules share lives in
    ``tests/helpers/`` (a module per idea), so a test module can be renamed, moved or deleted
    alone, and ``pythonpath`` needs only ``tests``."""
    tests = REPO / "tests"
    files = sorted(tests.rglob("*.py"))
    test_modules = {path.stem for path in files if path.name.startswith("test_")}
    assert {"test_imports", "test_intphys", "test_store"} <= test_modules
    imports = {path: imported_modules(path) for path in files}
    assert "helpers.intphys" in imports[tests / "model" / "scorers" / "test_cue_scorer.py"]
    offenders = {
        f"{path.relative_to(REPO)}: {module}"
        for path, modules in imports.items()
        for module in modules
        if any(part in test_modules for part in module.split("."))
    }
    assert offenders == set()


def command_line_imports(path: Path) -> list[int]:
    """The lines of the module at ``path`` that import ``voe_lightning.cli`` or a module of it."""

    def names(node: ast.AST) -> list[str]:
        if isinstance(node, ast.Import):
            return [alias.name for alias in node.names]
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            return [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
        return []

    return [
        node.lineno
        for node in ast.walk(ast.parse(path.read_text(), str(path)))
        if any(
            name == "voe_lightning.cli" or name.startswith("voe_lightning.cli.")
            for name in names(node)
        )
    ]


def test_only_the_entry_point_imports_the_command_line():
    """The command line parses, checks and dispatches: no other module of the package (but
    ``__main__``, which runs it), and no benchmark or experiment, imports from it."""
    sources = [
        path
        for name, path in module_files().items()
        if name != "voe_lightning.__main__" and not name.startswith("voe_lightning.cli")
    ]
    sources += [
        path for folder in ("benchmarks", "experiments") for path in (REPO / folder).rglob("*.py")
    ]
    assert REPO / "voe_lightning" / "analysis" / "null.py" in sources
    offenders = {
        f"{path.relative_to(REPO)}:{line}"
        for path in sources
        for line in command_line_imports(path)
    }
    assert offenders == set()


def test_every_script_imports_modules_that_exist():
    """Each script of benchmarks/ and experiments/ imports only modules that can be found from
    its own folder (a sibling it names by a file name that was renamed would fail only when a
    reader runs it)."""
    import importlib.util

    missing = []
    for path in sorted(p for f in ("benchmarks", "experiments") for p in (REPO / f).glob("*.py")):
        sys.path.insert(0, str(path.parent))
        try:
            for node in ast.walk(ast.parse(path.read_text())):
                names = (
                    [alias.name for alias in node.names]
                    if isinstance(node, ast.Import)
                    else [node.module]
                    if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
                    else []
                )
                missing += [
                    f"{path.relative_to(REPO)}: {name}"
                    for name in names
                    if importlib.util.find_spec(name.split(".")[0]) is None
                ]
        finally:
            sys.path.remove(str(path.parent))
    assert missing == []
