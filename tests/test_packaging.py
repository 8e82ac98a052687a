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
