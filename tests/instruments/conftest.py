"""Fixtures of the instrument tests: the simulated bench on a virtual clock, real sensor curves."""

from pathlib import Path

import pytest

from drivers.clock import VirtualClock
from cryod.thermometry import load_calibration
from simulated_hw.bench import SimulatedBench

CALIBRATION = Path(__file__).resolve().parent.parent / "data" / "calibration"
HEATER_RESISTANCE_OHM = 50.0


@pytest.fixture(scope="session")
def flange_curve():
    """X186279 (the flange Cernox, T2), from the tests' copy of the .340 file."""
    return load_calibration(CALIBRATION / "X186279.340")


@pytest.fixture(scope="session")
def ptc_stage_curve():
    """X207058 (the PTC-stage Cernox, T5)."""
    return load_calibration(CALIBRATION / "X207058.340")


@pytest.fixture
def clock():
    return VirtualClock()


@pytest.fixture
def bench(clock, flange_curve, ptc_stage_curve):
    """Simulated lab with a 6221, noise-free so readings can be compared exactly."""
    return SimulatedBench(clock, flange_curve, ptc_stage_curve, heater_resistance_ohm=HEATER_RESISTANCE_OHM,
                          supply="6221", noise=False)


@pytest.fixture
def noisy_bench(clock, flange_curve, ptc_stage_curve):
    return SimulatedBench(clock, flange_curve, ptc_stage_curve, heater_resistance_ohm=HEATER_RESISTANCE_OHM,
                          seed=3)
