"""No import cycle between msa_slam's modules: a cycle works only as long as the modules happen to be imported in
one order, and it ties their layers together. Imports anywhere in a module count (inside functions too), except
those under `if TYPE_CHECKING:`, which never run."""

from __future__ import annotations

import ast
import graphlib
from pathlib import Path

import pytest

import msa_slam

PACKAGE_DIR = Path(msa_slam.__file__).resolve().parent


def _modules(package_dir: Path) -> dict[str, Path]:
    """Dotted name -> source file of every module and package under `package_dir`."""
    modules = {}
    for path in package_dir.rglob("*.py"):
        parts = path.relative_to(package_dir.parent).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def _type_checking(node: ast.AST) -> bool:
    test = getattr(node, "test", None)
    return isinstance(node, ast.If) and (
        getattr(test, "id", None) == "TYPE_CHECKING" or getattr(test, "attr", None) == "TYPE_CHECKING"
    )


def _imported(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The msa_slam modules that module `name` imports at run time (`from P import N`: P.N when N is a module,
    else P)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    todo, found = list(ast.parse(path.read_text(), str(path)).body), set()
    while todo:
        node = todo.pop()
        if _type_checking(node):
            todo += node.orelse
            continue
        todo += [child for child in ast.iter_child_nodes(node) if isinstance(child, ast.stmt)]
        if isinstance(node, ast.Import):
            named = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1]) if node.level else ""
            module = ".".join(part for part in (base, node.module) if part)
            named = [f"{module}.{a.name}" if f"{module}.{a.name}" in modules else module for a in node.names]
        else:
            continue
        for module in named:
            while module and module not in modules:  # `import msa_slam.sim.config as c` names the module
                module = module.rpartition(".")[0]
            if module and module != name:
                found.add(module)
    return found


def import_graph(package_dir: Path) -> dict[str, set[str]]:
    """Module -> the msa_slam modules it imports at run time."""
    modules = _modules(package_dir)
    return {name: _imported(name, path, modules) for name, path in modules.items()}


def test_no_import_cycle_between_msa_slam_modules():
    graph = import_graph(PACKAGE_DIR)
    assert "msa_slam.datasets.clouds" in graph["msa_slam.datasets"]  # the walk sees the package's imports
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as exc:
        pytest.fail(f"import cycle: {' -> '.join(exc.args[1])}")


def test_a_cycle_is_found_and_type_checking_imports_are_not(tmp_path):
    package = tmp_path / "msa_slam"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from msa_slam import b\n")
    (package / "b.py").write_text("def f():\n    from msa_slam.a import x\n")
    assert graphlib.TopologicalSorter(import_graph(package)).static_order()  # a -> b under TYPE_CHECKING only
    (package / "a.py").write_text("from msa_slam import b\n")
    with pytest.raises(graphlib.CycleError):
        graphlib.TopologicalSorter(import_graph(package)).prepare()


def _package(module: str) -> str:
    """The top-level package of a module (msa_slam.X for msa_slam.X.y); a top-level module stands for itself."""
    return ".".join(module.split(".")[:2])


def package_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Package -> the other msa_slam packages its modules import at run time."""
    packages: dict[str, set[str]] = {}
    for module, imported in graph.items():
        own = _package(module)
        packages.setdefault(own, set()).update(p for p in map(_package, imported) if p != own)
    return packages


def test_no_import_cycle_between_msa_slam_packages():
    """Layers: no package imports one that imports it back, even through modules that form no cycle themselves
    (reporting/ writing a study's report through experiments/, which writes its runs through reporting/)."""
    graph = package_graph(import_graph(PACKAGE_DIR))
    assert "msa_slam.pipeline" in graph["msa_slam.experiments"]  # experiments/ runs the pipeline
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as exc:
        pytest.fail(f"import cycle between packages: {' -> '.join(exc.args[1])}")


def test_a_cycle_between_packages_is_found(tmp_path):
    package = tmp_path / "msa_slam"
    for name in ("a", "b"):
        (package / name).mkdir(parents=True)
        (package / name / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "a" / "low.py").write_text("")
    (package / "a" / "high.py").write_text("from msa_slam.b import low\n")
    (package / "b" / "low.py").write_text("from msa_slam.a import low\n")
    graph = import_graph(package)
    graphlib.TopologicalSorter(graph).prepare()  # no cycle between modules
    with pytest.raises(graphlib.CycleError):
        graphlib.TopologicalSorter(package_graph(graph)).prepare()
