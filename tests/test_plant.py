"""The simulated cryostat's physics against independent calculations."""

import math

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import simpson

from drivers.clock import VirtualClock
from cryod.cooler.line_fit import fit_line, wrap_phase
from cryod.model import (
    CoolerFrequencyDrift, CoolerHarmonic, CryostatPlant, DeadTime, HeatCapacityTemperature, HeaterNonlinearity,
    LinkDynamics, SensorLag, simulate,
)
from simulated_hw.cryostat import SimulatedCryostat

OMEGA = 10.83


def step_response(tf, times):
    """Independent: scipy's step response of a TransferFunction at given times."""
    times = np.asarray(times, dtype=float)
    out = np.zeros_like(times)
    positive = times > 0
    if positive.any():
        _, y = signal.step((tf.numerator, tf.denominator), T=np.concatenate(([0.0], times[positive])))
        out[positive] = y[1:]
    return out


def test_heater_writes_at_any_instant_are_exact(quiet_reference_model):
    model = quiet_reference_model
    generator = np.random.default_rng(3)
    write_times = np.sort(generator.uniform(0.0, 400.0, 25))
    powers = generator.uniform(0.0, 0.2, 25)
    read_times = np.sort(generator.uniform(0.0, 500.0, 60))
    plant = CryostatPlant(model)
    events = sorted([(t, "write", p) for t, p in zip(write_times, powers)] + [(t, "read", None) for t in read_times])
    got = {}
    for instant, kind, power in events:
        if kind == "write":
            plant.set_heater_power(power, instant)
        else:
            plant.advance_to(instant)
            got[instant] = plant.temperatures()
    steps = np.diff(np.concatenate(([0.0], powers)))
    for instant, (flange, stage) in got.items():
        expected_flange = 4.23 + sum(dp * step_response(model.heater_to_thermometer, [instant - tw])[0]
                                     for dp, tw in zip(steps, write_times))
        expected_stage = 3.34 + sum(dp * step_response(model.heater_to_ptc_stage, [instant - tw])[0]
                                    for dp, tw in zip(steps, write_times))
        assert flange == pytest.approx(expected_flange, abs=1e-10)
        assert stage == pytest.approx(expected_stage, abs=1e-10)


def test_ptc_response_is_the_exact_steady_state_at_any_instant(reference_model):
    """No aliasing: the line and a third harmonic (5.2 Hz, near the 6.25 Hz Nyquist of 80 ms) are exact."""
    model = reference_model.with_ptc(harmonics=(CoolerHarmonic(3, 0.01, 0.7),))
    instants = np.concatenate(([0.0], np.sort(np.random.default_rng(5).uniform(0.0, 100.0, 49))))
    path = model.ptc_heat_to_thermometer
    expected_flange = 4.23 + sum(
        abs(path.frequency_response(k * OMEGA)) * model.ptc.heat_capacity_J_per_K * k * OMEGA * b
        * np.cos(k * OMEGA * instants + phase + np.angle(path.frequency_response(k * OMEGA)))
        for k, b, phase in model.ptc.components())
    expected_stage = 3.34 + 0.12361 * np.sin(OMEGA * instants + 3.02) + 0.01 * np.sin(3 * OMEGA * instants + 0.7)
    record = simulate(model, instants, np.zeros(instants.size))
    np.testing.assert_allclose(record.flange_K, expected_flange, atol=1e-12)
    np.testing.assert_allclose(record.ptc_stage_K, expected_stage, atol=1e-12)


def test_mean_over_integration_window_matches_numerical_average(reference_model):
    model = reference_model.with_effects(sensor_lag=SensorLag(0.2, 0.05))
    plant = CryostatPlant(model, initial_heater_power_w=0.05)
    plant.set_heater_power(0.12, 3.0)
    plant.advance_to(3.37)
    mean_flange, mean_stage = plant.mean_temperatures(0.2)
    fine = np.linspace(3.37, 3.57, 4001)
    times = np.concatenate(([0.0, 3.0], fine))
    powers = np.concatenate(([0.05], np.full(fine.size + 1, 0.12)))
    record = simulate(model, times, powers, initial_heater_power_w=0.05)
    assert mean_flange == pytest.approx(simpson(record.flange_K[2:], x=fine) / 0.2, abs=1e-9)
    assert mean_stage == pytest.approx(simpson(record.ptc_stage_K[2:], x=fine) / 0.2, abs=1e-9)
    # the 200 ms window averages the line down: sinc(omega T / 2)
    assert abs(mean_stage - plant.temperatures()[1]) > 1e-3


EFFECTS = {
    "none": {},
    "sensor_lag": {"sensor_lag": SensorLag(0.3, 0.02)},
    "link_dynamics": {"link_dynamics": LinkDynamics(0.08, 1.2)},
    "dead_time": {"dead_time": DeadTime(1.37)},
    "heat_capacity_temperature": {"heat_capacity_temperature": HeatCapacityTemperature(1.5, 4.23)},
    "heater_nonlinearity": {"heater_nonlinearity": HeaterNonlinearity(0.5)},
    "ptc_frequency_drift": {"ptc_frequency_drift": CoolerFrequencyDrift(0.05, 0.002, 300.0)},
    "heat capacity with dead time and sensor lag": {
        "heat_capacity_temperature": HeatCapacityTemperature(-2.0, 4.5), "dead_time": DeadTime(0.53),
        "sensor_lag": SensorLag(0.2), "heater_nonlinearity": HeaterNonlinearity(-0.4)},
}


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_whole_record_equals_stepping_plant(reference_model, name):
    model = reference_model.with_effects(**EFFECTS[name])
    generator = np.random.default_rng(11)
    times = np.cumsum(generator.uniform(0.07, 0.09, 3000))
    powers = np.repeat(generator.uniform(0.0, 0.15, 30), 100)
    record = simulate(model, times, powers, initial_heater_power_w=0.02)
    plant = CryostatPlant(model, times[0], 0.02)
    for k in range(times.size):
        plant.advance_to(times[k])
        flange, stage = plant.temperatures()
        assert flange == pytest.approx(record.flange_K[k], abs=1e-10)
        assert stage == pytest.approx(record.ptc_stage_K[k], abs=1e-10)
        plant.set_heater_power(powers[k], times[k])


def test_dead_time_delays_the_heater_step_exactly(quiet_reference_model):
    times = np.arange(0.0, 300.0, 0.08)
    powers = np.full(times.size, 0.0088)
    base = simulate(quiet_reference_model, times, powers, initial_heater_power_w=0.0)
    delayed = simulate(quiet_reference_model.with_effects(dead_time=DeadTime(2.0)), times, powers,
                       initial_heater_power_w=0.0)
    shift = 25  # 2.0 s / 0.08 s
    np.testing.assert_allclose(delayed.flange_K[shift:], base.flange_K[:-shift], atol=1e-12)
    assert np.all(delayed.flange_K[:shift + 1] == 4.23)
    np.testing.assert_allclose(delayed.ptc_stage_K, base.ptc_stage_K, atol=1e-15)   # T5 path has no delay


def test_sensor_lag_filters_the_line(reference_model):
    tau = 0.3
    times = np.arange(0.0, 120.0, 0.08)
    base = simulate(reference_model, times, np.zeros(times.size))
    lagged = simulate(reference_model.with_effects(sensor_lag=SensorLag(tau)), times, np.zeros(times.size))
    fit_base = fit_line(times, base.flange_K, OMEGA)
    fit_lagged = fit_line(times, lagged.flange_K, OMEGA)
    assert fit_lagged.amplitude[0] / fit_base.amplitude[0] == pytest.approx(1 / math.hypot(1, OMEGA * tau), rel=1e-6)
    assert wrap_phase(fit_base.phase_rad[0] - fit_lagged.phase_rad[0]) == pytest.approx(math.atan(OMEGA * tau), abs=1e-6)


def test_link_dynamics_changes_only_the_ptc_path(reference_model, quiet_reference_model):
    effect = LinkDynamics(0.05, 1.2)
    times = np.arange(0.0, 120.0, 0.08)
    base = fit_line(times, simulate(reference_model, times, np.zeros(times.size)).flange_K, OMEGA)
    changed = fit_line(times, simulate(reference_model.with_effects(link_dynamics=effect), times,
                                       np.zeros(times.size)).flange_K, OMEGA)
    assert changed.amplitude[0] / base.amplitude[0] == pytest.approx(1.2 / math.hypot(1, OMEGA * 0.05), rel=1e-6)
    step = np.full(times.size, 0.0088)
    np.testing.assert_allclose(
        simulate(quiet_reference_model.with_effects(link_dynamics=effect), times, step, initial_heater_power_w=0).flange_K,
        simulate(quiet_reference_model, times, step, initial_heater_power_w=0).flange_K, atol=1e-15)


def test_heat_capacity_scales_time_constants_with_temperature(quiet_reference_model):
    """A 1 mW step on top of 113 mW (T2 near 5 K) with C ~ T^1.5 is the unscaled response, 1.285x slower."""
    exponent = 1.5
    model = quiet_reference_model.with_effects(heat_capacity_temperature=HeatCapacityTemperature(exponent, 4.23))
    held = 0.113
    times = np.arange(0.0, 1500.0, 0.08)
    response = simulate(model, times, np.full(times.size, held + 0.001), initial_heater_power_w=held).flange_K
    temperature = 4.23 + quiet_reference_model.heater_to_thermometer.dc_gain * held
    scale = (temperature / 4.23) ** exponent
    expected = 4.23 + model.heater_to_thermometer.dc_gain * held + 0.001 * step_response(
        model.heater_to_thermometer, times / scale)
    np.testing.assert_allclose(response, expected, atol=0.002 * 0.001 * 6.8)   # 0.2 % of the small step
    # and the static gain is unchanged
    assert response[-1] == pytest.approx(4.23 + 6.8182 * 0.114, abs=2e-4)


def test_heater_nonlinearity_changes_delivered_power(quiet_reference_model):
    model = quiet_reference_model.with_effects(heater_nonlinearity=HeaterNonlinearity(0.5))
    times = np.arange(0.0, 3000.0, 1.0)
    record = simulate(model, times, np.full(times.size, 0.1), initial_heater_power_w=0.1)
    assert record.flange_K[-1] == pytest.approx(4.23 + 6.8182 * (0.1 + 0.5 * 0.01), rel=1e-9)
    assert record.ptc_stage_K[-1] == pytest.approx(3.34 + 2.77 * 0.105, rel=1e-9)


def test_harmonics_reach_both_thermometers(reference_model):
    model = reference_model.with_ptc(harmonics=(CoolerHarmonic(2, 0.015, 0.4),))
    times = np.arange(0.0, 200.0, 0.01)
    record = simulate(model, times, np.zeros(times.size))
    stage = fit_line(times, record.ptc_stage_K, OMEGA, orders=2)
    flange = fit_line(times, record.flange_K, OMEGA, orders=2)
    assert stage.amplitude[1] == pytest.approx(0.015, rel=1e-6)
    assert stage.phase_rad[1] == pytest.approx(0.4, abs=1e-6)
    expected = abs(model.ptc_heat_to_thermometer.frequency_response(2 * OMEGA)) * 0.1655 * 2 * OMEGA * 0.015
    assert flange.amplitude[1] == pytest.approx(expected, rel=1e-5)


def test_frequency_drift_moves_the_phase(reference_model):
    rate = 0.036   # rad/s per hour
    model = reference_model.with_effects(ptc_frequency_drift=CoolerFrequencyDrift(rate_rad_s_per_hour=rate))
    times = np.arange(3000.0, 3060.0, 0.02)
    record = simulate(model, np.concatenate(([0.0], times)), np.zeros(times.size + 1))
    local = fit_line(times, record.ptc_stage_K[1:], OMEGA + rate * 3030.0 / 3600.0)
    expected_phase = 3.02 + 0.5 * rate * 3030.0 ** 2 / 3600.0 - rate * 3030.0 ** 2 / 3600.0
    assert local.amplitude[0] == pytest.approx(0.12361, rel=1e-3)
    assert wrap_phase(local.phase_rad[0] - expected_phase) == pytest.approx(0.0, abs=2e-3)


def test_noise_is_seeded_and_has_the_configured_rms(reference_model):
    def run(seed):
        clock = VirtualClock()
        cryostat = SimulatedCryostat(reference_model, clock, seed=seed)
        readings, truth = [], []
        for _ in range(4000):
            clock.advance(0.08)
            readings.append(cryostat.read_temperatures())
            truth.append(cryostat.true_temperatures())
        return np.array(readings), np.array(truth)

    first, truth = run(7)
    again, _ = run(7)
    other, _ = run(8)
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)
    noise = first - truth
    assert np.std(noise[:, 0]) == pytest.approx(20e-6, rel=0.05)
    assert np.std(noise[:, 1]) == pytest.approx(0.3e-3, rel=0.05)


def test_time_cannot_go_backwards_and_heater_cannot_cool(reference_model):
    plant = CryostatPlant(reference_model)
    plant.advance_to(10.0)
    with pytest.raises(ValueError, match="backwards"):
        plant.advance_to(5.0)
    cryostat = SimulatedCryostat(reference_model, VirtualClock())
    with pytest.raises(ValueError, match="negative"):
        cryostat.set_heater_power(-0.01)


@pytest.mark.parametrize("count", [0, 1, 63, 64, 65, 1000, 4097])
@pytest.mark.parametrize("kind", [float, complex])
def test_the_recurrence_scan_equals_the_sequential_loop(count, kind):
    from cryod.model.heater_path import linear_recurrence

    generator = np.random.default_rng(count)
    factors = np.exp(-generator.uniform(0.0, 3.0, count) * (1.0 + (0.7j if kind is complex else 0.0)))
    factors[generator.random(count) < 0.05] = 0.0            # a decay complete within one interval
    offsets = generator.normal(size=count) * (1.0 + (1j if kind is complex else 0.0))
    start = kind(0.3)
    expected = [start]
    for factor, offset in zip(factors, offsets):
        expected.append(factor * expected[-1] + offset)
    assert linear_recurrence(factors, offsets, start) == pytest.approx(np.array(expected), rel=1e-12, abs=1e-13)


def test_a_heat_capacity_replay_asked_again_is_the_same_and_a_changed_one_is_not(quiet_reference_model):
    """The fixed point of the heat-capacity effect is kept for the analysis's repeated replays of one record."""
    from cryod.model import dynamics

    generator = np.random.default_rng(5)
    times = np.cumsum(generator.uniform(0.07, 0.09, 5000))
    powers = np.repeat(generator.uniform(0.0, 0.15, 50), 100)

    def replay(exponent):
        model = quiet_reference_model.with_effects(heat_capacity_temperature=HeatCapacityTemperature(exponent, 4.23))
        return simulate(model, times, powers, initial_heater_power_w=0.02).flange_K

    dynamics._TIME_SCALED_RUNS.clear()
    first = replay(1.5)
    assert len(dynamics._TIME_SCALED_RUNS) == 1
    again = replay(1.5)
    assert len(dynamics._TIME_SCALED_RUNS) == 1                  # served from what was kept
    np.testing.assert_array_equal(again, first)
    other = replay(1.6)
    assert len(dynamics._TIME_SCALED_RUNS) == 2 and np.max(np.abs(other - first)) > 1e-5
    dynamics._TIME_SCALED_RUNS.clear()
    np.testing.assert_array_equal(replay(1.5), first)            # and it is what a fresh run gives


def test_a_model_built_with_a_list_still_simulates(reference_model):
    """The plant's transfer functions are kept per model; a model with unhashable parts is simply not kept."""
    listed = reference_model.with_ptc(harmonics=[CoolerHarmonic(2, 0.002, 0.3)])
    kept = reference_model.with_ptc(harmonics=(CoolerHarmonic(2, 0.002, 0.3),))
    times = np.arange(0.0, 50.0, 0.08)
    np.testing.assert_array_equal(simulate(listed, times, np.full(times.size, 0.1)).flange_K,
                                  simulate(kept, times, np.full(times.size, 0.1)).flange_K)
