"""The examples in every module's docstrings run and give what they show.

Every module of cryod, drivers and simulated_hw with a ``>>>`` example is
found here, so an example in a new module is tested without being listed.
"""

import doctest
import importlib
import pkgutil
from pathlib import Path

import pytest

REPOSITORY = Path(__file__).resolve().parent.parent
PACKAGES = ("cryod", "drivers", "simulated_hw")


def modules_with_examples() -> list[str]:
    names = []
    for package in PACKAGES:
        for module in pkgutil.walk_packages([str(REPOSITORY / package)], prefix=f"{package}."):
            path = REPOSITORY / (module.name.replace(".", "/") + ("/__init__.py" if module.ispkg else ".py"))
            if ">>> " in path.read_text(encoding="utf-8"):
                names.append(module.name)
    return sorted(names)


MODULES = modules_with_examples()


def test_the_examples_are_found():
    assert {"cryod.model.dynamics", "cryod.control.regulator", "drivers.keithley2002",
            "simulated_hw.scpi"} <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name, monkeypatch):
    monkeypatch.chdir(REPOSITORY)
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0
    assert result.attempted > 0 or "doctest: +SKIP" in Path(module.__file__).read_text()   # needs hardware
