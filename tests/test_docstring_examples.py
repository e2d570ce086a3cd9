"""The examples in the docstrings of the model tools run and give what they show."""

import doctest
import importlib

import pytest

MODULES = [
    "cryod.model", "cryod.model.parameters", "cryod.model.model_file", "cryod.model.transfer_function",
    "cryod.model.ptc_cycle", "cryod.model.heater_path", "cryod.model.ptc_path", "cryod.model.dynamics",
    "cryod.analysis.ptc_line", "cryod.analysis.noise", "cryod.analysis.record_data", "cryod.analysis.replay",
    "cryod.analysis.segments", "cryod.analysis.decision", "cryod.paper_table1", "simulated_hw.measurement_programs",
    "simulated_hw.hidden_effects",
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0
