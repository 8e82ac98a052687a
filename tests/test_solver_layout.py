"""The layout rules of solvers/: back-ends behind the registry never import one another,
nothing imports another module's private (``_x``) names, and every module stays small."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from solvers.allocation.backends import BACKEND_MODULES

ROOT = Path(__file__).resolve().parents[1]
SOLVERS = ROOT / "solvers"
MAX_MODULE_LINES = 600
# each back-end is the module or package the registry names (every module under it)
BACKEND_UNITS = dict(BACKEND_MODULES)


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def unit_of(module: str) -> str | None:
    """The back-end a module belongs to, or None for the shared modules."""
    for name, unit in BACKEND_UNITS.items():
        if module == unit or module.startswith(unit + "."):
            return name
    return None


def imports(source: str) -> list[tuple[str, list[str]]]:
    """(module, imported names) of every import statement, at any depth."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.module, [a.name for a in node.names]))
    return out


def violations(module: str, source: str) -> list[str]:
    """The layout rules broken by ``source`` (the text of ``module``)."""
    mine = unit_of(module)
    found = []
    for target, names in imports(source):
        if not target.startswith("solvers"):
            continue
        theirs = unit_of(target)
        if theirs is not None and theirs != mine:
            found.append(f"{module} imports back-end {theirs!r} ({target}); go through the registry")
        for name in names:
            if name.startswith("_") and target != module:
                found.append(f"{module} imports private {target}.{name}")
    return found


def solver_files() -> list[Path]:
    return sorted(p for p in SOLVERS.rglob("*.py") if "__pycache__" not in p.parts)


def test_the_rule_checker_catches_what_it_forbids() -> None:
    """The checker is not vacuous: a back-end reaching into another, and a private import
    anywhere, are reported; the registry and the shared modules are allowed."""
    assert violations("solvers.allocation.bnb", "from solvers.allocation.cpsat import solve_ilp_cpsat\n")
    assert violations("solvers.allocation.highs", "def f():\n    import solvers.allocation.semigreedy.prepare\n")
    assert violations("solvers.sequencing.passes", "from solvers.sequencing.state import _hidden\n")
    assert violations("solvers.allocation.semigreedy.solve", "from solvers.allocation.bnb import BACKEND\n")
    assert not violations("solvers.allocation.bnb", "from solvers.allocation.backends import get_backend\n"
                                                    "from solvers.allocation.bitset import prune_columns\n")
    assert not violations("solvers.allocation.semigreedy.solve",
                          "from solvers.allocation.semigreedy.prepare import prepare\n")


def test_every_backend_unit_exists_and_is_registered() -> None:
    assert set(BACKEND_UNITS) == {"bnb", "highs", "cpsat", "semigreedy"}
    files = {module_name(p) for p in solver_files()}
    for unit in BACKEND_UNITS.values():
        assert unit in files, unit


@pytest.mark.parametrize("path", solver_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_module_keeps_the_layout_rules(path: Path) -> None:
    text = path.read_text()
    assert violations(module_name(path), text) == []
    n_lines = text.count("\n")
    assert n_lines <= MAX_MODULE_LINES, f"{path.name}: {n_lines} lines > {MAX_MODULE_LINES}"


def test_shared_modules_import_no_backend_at_module_level() -> None:
    """The shared layers (the model, the exact-model helpers, sequencing, segmentation)
    reach an engine only through the registry, at call time."""
    for path in solver_files():
        module = module_name(path)
        if unit_of(module) is not None or module in ("solvers.allocation", "solvers.allocation.backends"):
            continue
        tree = ast.parse(path.read_text())
        for node in tree.body:
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                assert unit_of(node.module) is None, f"{module} imports {node.module}"
