"""The temperature-dependent cryostat: the shipped model at its operating point, the laws away from it."""

import dataclasses

import numpy as np
import pytest

from cryod.analysis import paper_table1 as table1
from cryod.model import (
    TEMPERATURE_MODEL_PATH, CryostatPlant, TemperatureDependentPlant, linearised_at, load_model, load_model_text,
    save_model, simulate, steady_state,
)
from cryod.model.temperature_plant import flange_temperature_at
from drivers.clock import VirtualClock
from cryod.yaml_source import FileFormatError
from simulated_hw.cryostat import SimulatedCryostat
from tests.table1_experiments import open_loop_line, step_responses


@pytest.fixture(scope="module")
def temperature_model():
    return load_model(TEMPERATURE_MODEL_PATH)


def test_at_its_operating_point_it_reproduces_table_1(temperature_model):
    times, flange, stage = step_responses(temperature_model, 3000.0)
    measured = table1.flange_step_response_K(times) - table1.FLANGE_START_K
    assert np.max(np.abs(flange - measured)) / measured[-1] < 0.01          # T2 step: 1 % of its height
    height = stage[-1] / (1 - np.exp(-3000.0 / 135.0))
    assert height == pytest.approx(0.024, abs=0.0005)
    line, stage_line, lag = open_loop_line(temperature_model)
    assert line == pytest.approx(table1.FLANGE_LINE_AMPLITUDE_K, rel=0.02)
    assert lag == pytest.approx(table1.FLANGE_LAG_BEHIND_PTC_STAGE_RAD, abs=0.03)
    assert stage_line == pytest.approx(0.1236, rel=1e-3)


def test_linearised_at_its_operating_point_it_is_the_shipped_model(temperature_model, reference_model):
    local = linearised_at(temperature_model, temperature_model.operating_point.flange_temperature_K)
    omega = np.array([1e-4, 1e-2, 0.3, 10.83, 32.5])
    for path in ("heater_to_thermometer", "ptc_heat_to_thermometer"):
        np.testing.assert_allclose(getattr(local, path).frequency_response(omega),
                                   getattr(reference_model, path).frequency_response(omega), rtol=1e-9)
    np.testing.assert_allclose(local.heater_to_ptc_stage.frequency_response(omega),
                               reference_model.heater_to_ptc_stage.frequency_response(omega), rtol=1e-12)
    assert local.ptc.ptc_stage_amplitude_K == pytest.approx(reference_model.ptc.ptc_stage_amplitude_K)
    assert local.operating_point.flange_temperature_K == pytest.approx(4.23)


@pytest.mark.parametrize("setpoint_K", [5.0, 12.0])
def test_small_steps_follow_the_linear_model_at_their_temperature(temperature_model, setpoint_K):
    """A 10 mW step from the steady state at a temperature: the plant against its tangent model (no line)."""
    quiet = temperature_model.with_ptc(ptc_stage_amplitude_K=0.0)
    power_w, _ = steady_state(quiet, setpoint_K)
    times = np.arange(0.0, 1500.0, 0.4)
    heater = np.full(times.size, power_w + 0.01)
    plant = simulate(quiet, times, heater, initial_heater_power_w=power_w).flange_K - setpoint_K
    tangent = simulate(linearised_at(quiet, setpoint_K), times, heater, initial_heater_power_w=power_w).flange_K \
        - setpoint_K
    assert abs(tangent[-1]) > 1e-3
    assert np.max(np.abs(plant - tangent)) < 0.01 * abs(tangent[-1])


def test_from_5_to_24_K_the_plant_is_slower_and_weaker_at_the_line(temperature_model):
    omega = temperature_model.ptc.angular_frequency_rad_s
    at_5, at_20 = linearised_at(temperature_model, 5.0), linearised_at(temperature_model, 20.0)
    assert max(at_20.heater_to_thermometer.time_constants_s) > 10 * max(at_5.heater_to_thermometer.time_constants_s)
    assert abs(at_20.heater_to_thermometer.frequency_response(omega)) \
        < 0.2 * abs(at_5.heater_to_thermometer.frequency_response(omega))
    line_5, line_20 = (abs(model.ptc_heat_to_thermometer.frequency_response(omega)) * model.ptc.heat_capacity_J_per_K
                       * omega * model.ptc.ptc_stage_amplitude_K for model in (at_5, at_20))
    assert line_20 < 0.1 * line_5
    powers = [steady_state(temperature_model, temperature)[0] for temperature in (5.0, 8.0, 12.0, 16.0, 20.0, 24.0)]
    assert np.all(np.diff(powers) > 0.0)
    assert powers[0] == pytest.approx(0.110, rel=0.15)       # the paper's "about 110 mW" at 5 K
    assert flange_temperature_at(temperature_model, powers[-1])[0] == pytest.approx(24.0, abs=1e-9)


def test_the_simulated_cryostat_and_whole_records_use_the_temperature_dependent_plant(temperature_model):
    cryostat = SimulatedCryostat(temperature_model, VirtualClock(), seed=1, noise=False,
                                 initial_heater_power_w=steady_state(temperature_model, 12.0)[0])
    assert isinstance(cryostat.plant, TemperatureDependentPlant)
    assert cryostat.read_temperatures()[0] == pytest.approx(12.0, abs=2e-4)
    assert type(SimulatedCryostat(load_model(), VirtualClock()).plant) is CryostatPlant


def test_the_section_round_trips_and_bad_sections_name_file_line_and_key(temperature_model, tmp_path):
    path = save_model(temperature_model, tmp_path / "model.yaml")
    assert load_model(path).temperature_dependence == temperature_model.temperature_dependence
    text = TEMPERATURE_MODEL_PATH.read_text()
    with pytest.raises(FileFormatError) as caught:
        load_model_text(text.replace("conductance_exponent: 1.0", "conductance_exponent: 7"), "t.yaml")
    assert caught.value.key == "temperature_dependence.conductance_exponent" and "at most 4" in caught.value.reason
    assert caught.value.line == next(number for number, line in enumerate(text.splitlines(), 1)
                                     if "conductance_exponent:" in line)
    with pytest.raises(FileFormatError, match="takes no effects"):
        load_model_text(text.replace("effects: {}", "effects: {dead_time: {heater_to_flange_s: 1.0}}"), "t.yaml")
    with pytest.raises(ValueError, match="both be 0"):
        dataclasses.replace(temperature_model.temperature_dependence, gamma_J_per_mol_K2=0.0, beta_J_per_mol_K4=0.0)
