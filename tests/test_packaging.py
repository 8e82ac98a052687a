"""The installed package (``pip install .``, the Docker image) holds every source package.

An editable install finds sub-packages through the source tree, so a package left out of the
build configuration only breaks the wheel and the image. These tests compare the build
configuration with the tree, and the Dockerfile with the top-level packages.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from setuptools import find_packages

ROOT = Path(__file__).resolve().parents[1]
TOP_LEVEL = ("models", "solvers", "planner", "service")


def _source_packages() -> set[str]:
    found = set()
    for top in TOP_LEVEL:
        for init in (ROOT / top).rglob("__init__.py"):
            found.add(".".join(init.parent.relative_to(ROOT).parts))
    return found


def _configured_packages() -> set[str]:
    setuptools_cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    if "packages" in setuptools_cfg and isinstance(setuptools_cfg["packages"], list):
        return set(setuptools_cfg["packages"])
    include = setuptools_cfg["packages"]["find"]["include"]
    return set(find_packages(where=str(ROOT), include=include))


def test_build_configuration_lists_every_source_package():
    missing = _source_packages() - _configured_packages()
    assert not missing, f"packages missing from the wheel: {sorted(missing)}"


def test_build_configuration_ships_no_tests_or_benchmarks():
    shipped = {name.split(".")[0] for name in _configured_packages()}
    assert shipped == set(TOP_LEVEL)


def test_dockerfile_copies_every_top_level_package():
    dockerfile = (ROOT / "Dockerfile").read_text()
    for top in TOP_LEVEL:
        assert f"COPY {top} ./{top}" in dockerfile, top


def _imported_top_names(top: str) -> set[str]:
    """Top-level modules imported anywhere in package ``top`` (AST, every nesting level)."""
    import ast

    names = set()
    for path in (ROOT / top).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names


# imported only behind a guard that names the extra in its message (service/settings.py)
OPTIONAL_IMPORTS = {"distributed": "distributed"}


def _requirement_closure(requirements: list[str]) -> set[str]:
    """The distributions that installing ``requirements`` brings (no extras followed)."""
    import re
    from importlib.metadata import PackageNotFoundError, requires

    def name(req: str) -> str:
        return re.split(r"[<>=!~;\[ (]", req.strip(), maxsplit=1)[0].lower().replace("_", "-")

    todo, seen = [name(r) for r in requirements], set()
    while todo:
        dist = todo.pop()
        if dist in seen:
            continue
        seen.add(dist)
        try:
            reqs = requires(dist) or []
        except PackageNotFoundError:
            continue
        todo.extend(name(r) for r in reqs if "extra ==" not in r.replace('"', "").replace("'", ""))
    return seen


def test_every_run_time_import_is_a_base_dependency():
    """A third-party module the shipped packages import is installed by ``pip install .``
    (no extras): its distribution is a base dependency or one of theirs."""
    import sys
    from importlib.metadata import packages_distributions

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    base = _requirement_closure(project["dependencies"])
    owners = packages_distributions()
    undeclared = {}
    for top in TOP_LEVEL:
        for mod in _imported_top_names(top) - set(TOP_LEVEL) - set(sys.stdlib_module_names):
            if mod in OPTIONAL_IMPORTS:
                assert OPTIONAL_IMPORTS[mod] in project["optional-dependencies"], mod
                continue
            dists = {d.lower().replace("_", "-") for d in owners.get(mod, [])}
            assert dists, f"{top} imports {mod!r}, which no installed distribution provides"
            if not dists & base:
                undeclared[mod] = sorted(dists)
    assert not undeclared, f"run-time imports missing from the base dependencies: {undeclared}"
