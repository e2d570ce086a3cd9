"""The examples in the instrument modules' docstrings run and give what they show."""

import doctest
import importlib

import pytest

MODULES = ["drivers.errors", "drivers.scpi", "drivers.keithley2002_timing", "drivers.keithley2002",
           "drivers.keithley6221", "drivers.keithley2400", "drivers.trigger_lines", "drivers.thermometer_pair",
           "drivers.transports.prologix", "simulated_hw.scpi", "simulated_hw.scpi_server", "simulated_hw.status"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert result.failed == 0
