"""The examples in the docstrings of the model tools run and give what they show."""

import doctest
import importlib

import pytest

MODULES = [
    "cryod.analysis.ptc_line", "cryod.analysis.noise", "cryod.analysis.record_data", "cryod.analysis.replay",
    "cryod.analysis.segments", "cryod.analysis.decision", "cryod.paper_table1", "simulated_hw.protocols",
    "simulated_hw.hidden_effects", "cryod.control.feedforward_limit", "cryod.control.bounded_waveform",
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0
