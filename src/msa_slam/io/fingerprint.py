"""Fingerprints of msa-slam's own code, so that a cache entry or a finished experiment cell made by other code
is never reused (the package version, unchanged between releases, cannot tell).

A fingerprint is the SHA-256 of the source files that compute a result: every module of the packages named
(`msa_slam.descriptors`: all its modules, including the ones it imports by name at run time) and the static
import closure of those modules within msa_slam (Import and ImportFrom nodes anywhere in a module's syntax
tree, inside functions too), with the `__init__.py` of every package on the way (importing a module runs
them), plus package data files named by glob (e.g. the simulator's shipped trajectories). Files are hashed
by their path relative to the package folder, in sorted order, so the fingerprint does not depend on where
msa-slam is installed; it is computed once per process.
"""

from __future__ import annotations

import ast
import functools
import hashlib
from collections.abc import Iterable, Iterator
from pathlib import Path

import msa_slam

PACKAGE = "msa_slam"
PACKAGE_DIR = Path(msa_slam.__file__).resolve().parent


def code_fingerprint(modules: Iterable[str], data: Iterable[str] = (), package_dir: Path | None = None) -> str:
    """SHA-256 (hex) of the sources of `modules` (dotted names of msa_slam's packages or modules), of their
    import closure within msa_slam and of the package data files matching the `data` globs; `package_dir`
    (default: the installed package) is the folder holding msa_slam's sources."""
    return _fingerprint(tuple(sorted(modules)), tuple(sorted(data)), package_dir or PACKAGE_DIR)


@functools.cache
def _fingerprint(modules: tuple[str, ...], data: tuple[str, ...], package_dir: Path) -> str:
    files = {_module_file(name, package_dir) for name in import_closure(modules, package_dir)}
    files |= {path for pattern in data for path in package_dir.glob(pattern) if path.is_file()}
    digest = hashlib.sha256()
    for path in sorted(files, key=lambda p: p.relative_to(package_dir).as_posix()):
        digest.update(
            f"{path.relative_to(package_dir).as_posix()}\0{hashlib.sha256(path.read_bytes()).hexdigest()}\n".encode()
        )
    return digest.hexdigest()


def import_closure(modules: Iterable[str], package_dir: Path) -> set[str]:
    """Dotted names of `modules` (a package stands for all its modules), of the msa_slam modules they import,
    transitively, and of the packages holding them."""
    todo = [sub for name in modules for sub in _package_modules(name, package_dir)]
    seen: set[str] = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        parts = name.split(".")
        todo += [".".join(parts[:i]) for i in range(1, len(parts))]
        todo += _imports(name, package_dir)
    return seen


def _source(name: str, package_dir: Path) -> Path | None:
    """The file of module or package `name` under `package_dir`, None when it is not one of msa_slam's."""
    if name != PACKAGE and not name.startswith(f"{PACKAGE}."):
        return None
    path = package_dir.joinpath(*name.split(".")[1:])
    for candidate in (path / "__init__.py", path.with_suffix(".py")):
        if candidate.is_file():
            return candidate
    return None


def _module_file(name: str, package_dir: Path) -> Path:
    """The file of `name`, which must be one of msa_slam's modules or packages."""
    source = _source(name, package_dir)
    if source is None:
        raise ValueError(f"{name}: not a module of {PACKAGE} in {package_dir}")
    return source


def _package_modules(name: str, package_dir: Path) -> list[str]:
    """`name` and, for a package, every module below it."""
    source = _module_file(name, package_dir)
    if source.name != "__init__.py":
        return [name]
    found = [path.relative_to(package_dir).with_suffix("").parts for path in source.parent.rglob("*.py")]
    return [".".join((PACKAGE, *(parts[:-1] if parts[-1] == "__init__" else parts))) for parts in found]


@functools.cache  # each file parsed once per process, whichever fingerprints include it
def _imports(name: str, package_dir: Path) -> list[str]:
    """The msa_slam modules and packages that module `name` imports anywhere in its code (`from P import N`
    counts P, and P.N when N is a module)."""
    source = _module_file(name, package_dir)
    package = name if source.name == "__init__.py" else name.rpartition(".")[0]
    named: list[str] = []
    for node in _statements(ast.parse(source.read_bytes(), str(source)).body):
        if isinstance(node, ast.Import):
            named += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1]) if node.level else ""
            module = ".".join(part for part in (base, node.module) if part)
            named += [module, *(f"{module}.{alias.name}" for alias in node.names)]
    return [module for module in named if _source(module, package_dir) is not None]


def _statements(nodes: list) -> Iterator[ast.AST]:
    """Every statement of `nodes` and of the blocks nested in them (functions, classes, if, try, with, match):
    imports are statements, so expressions need not be walked (several times faster than ast.walk)."""
    for node in nodes:
        yield node
        for block in ("body", "orelse", "finalbody", "handlers", "cases"):
            inner = getattr(node, block, None)
            if isinstance(inner, list):
                yield from _statements(inner)
