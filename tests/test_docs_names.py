"""The docs name code that exists, where it lives: dotted names, source paths and the layers' contract.

A module moved or an object moved to another module leaves the docs pointing at nothing (or at a
re-export the reader then cannot find the code of); docs/developer/architecture.md shows the layers' contract,
which must say what pyproject.toml enforces.
"""

import importlib
import inspect
import re
import tomllib

import pytest

from tests.conftest import REPOSITORY

#: The pages of the site (the figures' generated reports aside), the benchmarks' results and the README.
DOCS = (sorted(path for path in (REPOSITORY / "docs").rglob("*.md") if "figures" not in path.parts)
        + sorted((REPOSITORY / "benchmarks" / "results").glob("*.md")) + [REPOSITORY / "README.md"])
# cryod.x.y, not a file name (cryod.yaml) nor a logger's name in a journal line (`cryod.loop: warning: ...`)
DOTTED_NAME = re.compile(r"(?<![\w./-])((?:cryod|drivers|simulated_hw)(?:\.[A-Za-z_]\w*)+)(?![\w/-]|\.\w|: )")
FILE_SUFFIXES = {"yaml", "conf", "service", "csv", "md", "py"}
SOURCE_PATH = re.compile(r"(?<![\w/.~-])((?:cryod|drivers|simulated_hw|tests|benchmarks)/[\w/]+(?:\.py\b|/))")


def _where_it_fails(name: str) -> str | None:
    """None when ``name`` is a module, or an object of the module it names (a package may re-export)."""
    parts = name.split(".")
    for length in range(len(parts), 0, -1):
        try:
            module = importlib.import_module(".".join(parts[:length]))
        except ModuleNotFoundError:
            continue
        named = module
        for part in parts[length:]:
            if not hasattr(named, part):
                return f"{module.__name__} has no {part}"
            named = getattr(named, part)
        defined_in = getattr(named, "__module__", module.__name__)
        if (length < len(parts) and not hasattr(module, "__path__")
                and (inspect.isclass(named) or inspect.isfunction(named)) and defined_in != module.__name__):
            return f"it lives in {defined_in}"
        return None
    return "no such module"


def _named(pattern):
    return [(doc.relative_to(REPOSITORY), found) for doc in DOCS for found in sorted(set(pattern.findall(
        doc.read_text(encoding="utf-8"))))]


def test_every_dotted_name_in_the_docs_is_where_they_say():
    names = [(doc, name) for doc, name in _named(DOTTED_NAME) if name.rpartition(".")[2] not in FILE_SUFFIXES]
    assert len(names) > 30
    wrong = [f"{doc}: {name}: {problem}" for doc, name in names if (problem := _where_it_fails(name))]
    assert wrong == []


def test_every_source_path_in_the_docs_exists():
    paths = _named(SOURCE_PATH)
    assert len(paths) > 100
    assert [f"{doc}: {path}" for doc, path in paths if not (REPOSITORY / path).exists()] == []


def _layers(layers: list[str]) -> list[list[str]]:
    return [[part.strip() for part in re.split(r"[:|]", layer)] for layer in layers]


def test_the_architecture_page_shows_pyprojects_layers_contract():
    """The excerpt may shorten a layer's list with ``...``; every layer, its parts and their order, and
    whether two parts may import each other (``:``) or not (``|``) are as in pyproject.toml."""
    page = (REPOSITORY / "docs" / "developer" / "architecture.md").read_text(encoding="utf-8")
    excerpt = re.search(r"```toml\n(\[\[tool\.importlinter\.contracts\]\].*?)```", page, re.S)
    assert excerpt, "docs/developer/architecture.md shows the contract in a ```toml block"
    shown = tomllib.loads(excerpt.group(1))["tool"]["importlinter"]["contracts"][0]
    pyproject = tomllib.loads((REPOSITORY / "pyproject.toml").read_text(encoding="utf-8"))
    (enforced,) = [contract for contract in pyproject["tool"]["importlinter"]["contracts"]
                   if contract["id"] == shown["id"]]
    assert shown["type"] == enforced["type"] and len(shown["layers"]) == len(enforced["layers"])
    for page_layer, layer in zip(shown["layers"], enforced["layers"]):
        if " ... " in page_layer:
            head, tail = page_layer.split(" ... ")
            assert layer.startswith(head) and layer.endswith(tail), (page_layer, layer)
        else:
            assert page_layer == layer
    assert "ignore_imports" not in enforced, "docs/developer/architecture.md says the contract has no exceptions"


@pytest.mark.parametrize("name, problem", [
    ("cryod.records.metrics.periodic_amplitudes", "it lives in cryod.cooler.periodic"),
    ("cryod.paper_table1", "cryod has no paper_table1"),
    ("cryod.model.simulate", None),                         # a package's re-export is where a reader looks
])
def test_a_moved_name_is_found(name, problem):
    assert _where_it_fails(name) == problem
