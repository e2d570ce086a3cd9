"""The layers of pyproject.toml's import-linter contract hold, and every part of cryod is in one.

The contract (``[tool.importlinter]``) lists cryod's layers from the top (the command line) to the
bottom (the instrument drivers); a module imports only from its own layer and the ones below it.
docs/developer/architecture.md says what each layer holds. The tests have one rule of their own: a test
module imports no other test module (shared helpers live in helper modules and conftest.py).
"""

import ast
import pkgutil
import subprocess
import sys
import tomllib
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent
LINT = ("import sys\n"
        "from importlinter.cli import lint_imports\n"
        "sys.exit(lint_imports(config_filename='pyproject.toml', no_cache=True, no_logo=True))\n")


def _contract() -> dict:
    settings = tomllib.loads((REPOSITORY / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["importlinter"]
    (contract,) = [contract for contract in settings["contracts"] if contract["id"] == "layers"]
    return contract


def _layer_members(layer: str) -> list[str]:
    return [name.strip().strip("()") for name in layer.replace("|", ":").split(":")]


def test_imports_point_down_the_layers():
    result = subprocess.run([sys.executable, "-c", LINT], cwd=REPOSITORY, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


def test_every_part_of_cryod_is_in_a_layer():
    """A new module or package directly under cryod/ is given its layer, so the contract sees it."""
    members = {name for layer in _contract()["layers"] for name in _layer_members(layer)}
    parts = {f"cryod.{module.name}" for module in pkgutil.iter_modules([str(REPOSITORY / "cryod")])}
    assert parts - members == set(), "put these in a layer of pyproject.toml's import-linter contract"
    assert {"drivers", "simulated_hw"} <= members


def _imported_modules(tree: ast.Module):
    """(line, dotted name) of every module an ``import`` or ``from ... import`` names, nested ones too."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from ((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.lineno, node.module
            yield from ((node.lineno, f"{node.module}.{alias.name}") for alias in node.names)


def test_no_test_module_imports_another():
    """Collecting one test file must not run another's module code, and renaming or splitting a test module
    must not break others: what test modules share lives in a helper module or a conftest.py."""
    tests = REPOSITORY / "tests"
    found = []
    for path in sorted(tests.rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for line, name in _imported_modules(tree):
            if name.rpartition(".")[2].startswith("test_"):
                found.append(f"{path.relative_to(REPOSITORY)}:{line} imports {name}")
    assert found == [], "move what these share into a helper module of tests/ (or a conftest.py fixture)"
