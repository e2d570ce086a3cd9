"""The feedforward's physical limit: independent checks of the optimum, the physics figures
at 5 K (docs/explanation/feedforward.md), the certificate, convergence, and the command line."""

import itertools
import json
import math

import numpy as np
import pytest
from scipy import optimize, signal

from cryod.cli import main
from cryod.control.feedforward.bounded_waveform import best_bounded_waveform, largest_fundamental, residual_lower_bound
from cryod.control.feedforward.limit import (
    FeedforwardLimitError, feedforward_limit, limit_sweep, mean_heater_power_w, noise_floor_K,
)
from cryod.model import DeadTime, HeaterNonlinearity, CoolerHarmonic, SensorLag
from cryod.model import simulate

PERIOD_S = 0.08


@pytest.fixture(scope="module")
def at_5K(reference_model):
    """The example heater (50 ohm, 100 mA) at 5 K, sampled measure, certified."""
    return feedforward_limit(reference_model, 5.0, 50.0, 0.1)


# ---------------------------------------------------------------------------
# independent pieces: the plant's response by other means than the module's
# ---------------------------------------------------------------------------
def discretised_gain(model, orders):
    """Heater samples to T2 readings at harmonic n: scipy's zero-order-hold discretisation of G2 G1."""
    path = model.heater_to_thermometer
    numerator, denominator, _ = signal.cont2discrete((path.numerator, path.denominator), PERIOD_S, method="zoh")
    phases = np.mod(np.asarray(orders) * model.ptc.angular_frequency_rad_s * PERIOD_S, 2.0 * math.pi)
    return signal.freqz(np.ravel(numerator), denominator, worN=phases)[1]


def fitted_harmonics(time_s, values, phase, orders):
    """Complex amplitudes c_n of values ~ offset + Re sum c_n exp(j n phase), least squares."""
    columns = [np.ones_like(time_s)]
    for order in orders:
        columns += [np.cos(order * phase), -np.sin(order * phase)]
    coefficients = np.linalg.lstsq(np.array(columns).T, values, rcond=None)[0]
    return coefficients[1::2] + 1j * coefficients[2::2]


def simulated_line(model):
    """The cooler's line on T2 (phasor at theta = w0 t), from a noise-free simulation, heater off."""
    time_s = np.arange(0.0, 200.0, PERIOD_S)
    record = simulate(model, time_s, np.zeros_like(time_s))
    phase = model.ptc.angular_frequency_rad_s * time_s
    return fitted_harmonics(time_s, record.flange_K, phase, [1])[0]


def cooler_phase(model, time_s):
    """The phase of T5's fundamental as its thermometer reads it (A cos phase), fitted to a simulation."""
    record = simulate(model, time_s[:2500], np.zeros(2500))
    fundamental = fitted_harmonics(time_s[:2500], record.ptc_stage_K, model.ptc.angular_frequency_rad_s * time_s[:2500],
                                   [1])[0]
    return model.ptc.angular_frequency_rad_s * time_s + np.angle(fundamental)


def run_waveform(model, limit, duration_s=1500.0, settle_s=700.0, orders=range(1, 13)):
    """Simulate the loop holding the limit's waveform every 80 ms; harmonics of the T2 readings."""
    time_s = np.arange(0.0, duration_s, limit.period_s)
    phase = cooler_phase(model, time_s)
    orders_w = np.arange(1, limit.harmonics + 1)
    delivered = limit.mean_heater_power_W + (np.exp(1j * np.outer(phase, orders_w)) @ limit.waveform_harmonics_w).real
    commanded = np.interp(np.mod(phase, 2.0 * math.pi), limit.waveform_phase_rad, limit.waveform_power_w,
                          period=2.0 * math.pi) if model.effects.heater_nonlinearity else delivered
    record = simulate(model, time_s, commanded, initial_heater_power_w=float(np.mean(commanded)))
    kept = time_s > settle_s
    return np.abs(fitted_harmonics(time_s[kept], record.flange_K[kept], phase[kept], list(orders)))


def test_heater_response_through_the_hold_matches_scipys_discretisation(reference_model, at_5K):
    expected = discretised_gain(reference_model, [1])[0]
    assert at_5K.heater_gain_at_line_K_per_W == pytest.approx(abs(expected), rel=1e-7)
    assert at_5K.heater_phase_at_line_deg == pytest.approx(math.degrees(np.angle(expected)), abs=1e-5)


# ---------------------------------------------------------------------------
# (a) the optimum against independent checks
# ---------------------------------------------------------------------------
def test_optimum_agrees_with_an_exhaustive_search_over_two_harmonics(reference_model):
    """Waveforms with harmonics 1 and 2: exhaustive search over (|a_2|, relative phase), |a_1| exact.

    Shifting the phase rotates a_n by n tau, so the bounds depend only on |a_1|, |a_2| and
    beta = arg a_2 - 2 arg a_1; for each (|a_2|, beta) on a grid the largest admissible |a_1|
    follows from the bounds at 2048 phases, and the fundamental is turned against the line. The
    plant's numbers come from scipy's ZOH discretisation and a simulation, not from the module.
    """
    line = abs(simulated_line(reference_model))
    gain = np.abs(discretised_gain(reference_model, [1, 2]))
    mean, top = mean_heater_power_w(reference_model, 5.0), 0.5
    needed = line / gain[0]
    theta = np.linspace(0.0, 2.0 * math.pi, 1024, endpoint=False)
    cosine = np.cos(theta)
    second = np.linspace(0.0, mean, 301)
    best = math.inf
    for beta in np.linspace(0.0, 2.0 * math.pi, 360, endpoint=False):
        other = second[:, None] * np.cos(2.0 * theta + beta)            # the second harmonic's part
        with np.errstate(divide="ignore"):
            # |a_1| cos(theta) must keep mean + other + |a_1| cos(theta) within [0, top]
            upper = np.where(cosine > 0.0, (top - mean - other) / cosine, (0.0 - mean - other) / cosine)
        feasible = np.all((mean + other >= 0.0) & (mean + other <= top), axis=1)
        first = np.min(np.where(np.abs(cosine) > 1e-12, upper, np.inf), axis=1)
        left = np.maximum(0.0, line - gain[0] * np.minimum(first, needed))
        best = min(best, float(np.min(np.where(feasible, left ** 2 + (gain[1] * second) ** 2, np.inf))))
    brute_force = math.sqrt(best)

    limit = feedforward_limit(reference_model, 5.0, 50.0, 0.1, harmonics=2, certify=False)
    assert limit.whole_periodic_limit_K <= brute_force * (1.0 + 1e-4)
    assert limit.whole_periodic_limit_K >= brute_force * (1.0 - 3e-3)       # within the grid's resolution


def test_optimum_agrees_with_slsqp_on_the_amplitudes(reference_model):
    """The same programme over a_1..a_6, parametrised by the amplitudes and solved by SLSQP."""
    orders = np.arange(1, 7)
    line = np.zeros(6, complex)
    line[0] = simulated_line(reference_model)
    gain = discretised_gain(reference_model, orders)
    mean, top = mean_heater_power_w(reference_model, 5.0), 0.5
    theta = 2.0 * math.pi * np.arange(256) / 256
    basis = np.hstack([np.cos(np.outer(theta, orders)), -np.sin(np.outer(theta, orders))]) / top

    def objective(x):                    # x: real and imaginary parts of a_n, in units of the top power
        residual = line + gain * (x[:6] + 1j * x[6:]) * top
        return float(np.sum(np.abs(residual) ** 2)) * 1e6

    constraints = [{"type": "ineq", "fun": lambda x: mean / top + basis @ x * top},
                   {"type": "ineq", "fun": lambda x: (top - mean) / top - basis @ x * top}]
    result = optimize.minimize(objective, np.zeros(12), method="SLSQP", constraints=constraints,
                               options={"maxiter": 500, "ftol": 1e-14})
    slsqp = math.sqrt(result.fun * 1e-6)
    limit = feedforward_limit(reference_model, 5.0, 50.0, 0.1, harmonics=6, phase_points=256, certify=False)
    assert limit.whole_periodic_limit_K == pytest.approx(slsqp, rel=2e-4)


@pytest.mark.parametrize("effects", ["none", "delay, lag, nonlinearity, harmonic"])
def test_simulated_loop_leaves_exactly_the_predicted_harmonics(reference_model, effects):
    """The loop simulated in time, heater held 80 ms, readings at the ticks: the predicted residual."""
    model = reference_model
    if effects != "none":
        model = model.with_effects(dead_time=DeadTime(0.03), sensor_lag=SensorLag(0.1, 0.05),
                                   heater_nonlinearity=HeaterNonlinearity(0.4))
        model = model.with_ptc(harmonics=(CoolerHarmonic(order=2, ptc_stage_amplitude_K=0.012, phase_rad=0.4),))
    limit = feedforward_limit(model, 5.0, 50.0, 0.1, certify=False)
    measured = run_waveform(model, limit)
    tolerance = 0.5e-6 if effects == "none" else 3e-6       # commanded waveform interpolated on the grid
    assert np.allclose(measured[:6], limit.limit_harmonics_K, atol=tolerance)
    assert math.sqrt(np.sum(measured ** 2)) == pytest.approx(limit.whole_periodic_limit_K, abs=tolerance)


def test_continuous_time_optimum_is_worse_in_the_readings(reference_model, at_5K):
    """The waveform optimised for the thermometer's continuous signal, images of the hold ignored,
    leaves more in the loop's readings than the sampled optimum: the sampled measure is the right one."""
    continuous = feedforward_limit(reference_model, 5.0, 50.0, 0.1, measure="continuous", certify=False)
    measured = run_waveform(reference_model, continuous)
    assert math.sqrt(np.sum(measured[:6] ** 2)) > 1.15 * at_5K.ptc_periodic_limit_K


# ---------------------------------------------------------------------------
# the certificate
# ---------------------------------------------------------------------------
def test_lower_bound_brackets_the_limit(at_5K):
    assert at_5K.lower_bound_K <= at_5K.whole_periodic_limit_K <= 1.005 * at_5K.lower_bound_K


def test_no_coarse_waveform_beats_the_lower_bound(reference_model, at_5K):
    """Exhaustive search over 6-bin waveforms (levels on a grid, the last bin fixing the mean),
    harmonics 1-100 of the readings (fewer terms than the whole: a smaller value): none below the bound."""
    mean, top, bins = at_5K.mean_heater_power_W, at_5K.max_heater_power_W, 6
    levels = np.linspace(0.0, top, 9)
    grid = np.array(list(itertools.product(levels, repeat=bins - 1)))
    last = bins * mean - grid.sum(axis=1)
    waveforms = np.column_stack([grid, last])[(last >= 0.0) & (last <= top)]
    orders = np.arange(1, 101)
    edges = 2.0 * math.pi * np.arange(bins) / bins
    # a_n of a piecewise-constant waveform: (1/pi) sum_j P_j int_bin exp(-j n theta) d theta
    per_bin = np.exp(-1j * np.outer(edges, orders)) * (1.0 - np.exp(-2j * math.pi * orders / bins)) / (1j * math.pi * orders)
    amplitudes = waveforms @ per_bin
    line = np.zeros(orders.size, complex)
    line[0] = simulated_line(reference_model)
    totals = np.sqrt(np.sum(np.abs(line + discretised_gain(reference_model, orders) * amplitudes) ** 2, axis=1))
    assert totals.min() >= at_5K.lower_bound_K


def test_bounded_waveform_bound_holds_for_random_waveforms():
    """Any bounded waveform, of any harmonics, stays above the bound (h below every gain)."""
    generator = np.random.default_rng(3)
    line = np.array([1.0 + 0.5j, 0.2j, 0.0])
    gain = np.array([0.8 - 0.6j, 0.5 + 0.1j, 0.3])
    mean, low, high, floor = 0.4, 0.0, 1.0, 0.25
    best = best_bounded_waveform(line, gain, mean, low, high)
    bound = residual_lower_bound(line, gain, best, mean, low, high, floor)
    assert 0.0 < bound <= np.sum(np.abs(line + gain * best) ** 2)
    for _ in range(200):
        values = generator.uniform(low, high, 64)
        values = np.clip(mean + (values - values.mean()) * generator.uniform(0.1, 1.0), low, high)
        values += mean - values.mean()
        if values.min() < low or values.max() > high:
            continue
        amplitudes = np.fft.rfft(values)[1:33] * 2.0 / 64       # every harmonic of a 64-step waveform
        beyond = np.abs(amplitudes[3:]) ** 2 * floor ** 2       # higher harmonics at the least gain
        total = np.sum(np.abs(line + gain * amplitudes[:3]) ** 2) + np.sum(beyond)
        assert total >= bound


# ---------------------------------------------------------------------------
# (b) the physics figures at 5 K, from the model
# ---------------------------------------------------------------------------
def test_physics_figures_at_5K(reference_model, at_5K):
    assert at_5K.thermometer_gain_at_line_K_per_W == pytest.approx(7.1e-3, abs=0.1e-3)
    assert at_5K.thermometer_phase_at_line_deg == pytest.approx(-90.0, abs=3.0)
    assert at_5K.open_line_K == pytest.approx(1.73e-3, abs=0.05e-3)
    continuous = feedforward_limit(reference_model, 5.0, 50.0, 0.1, measure="continuous", certify=False)
    for limit in (at_5K, continuous):
        assert 0.22 < limit.line_power_needed_W < 0.26                         # "about 240 mW"
        assert 1.8 < limit.open_line_K / limit.best_sinusoid_K < 2.0         # "caps it near 1.9x"
    assert at_5K.mean_heater_power_W == pytest.approx(0.113, abs=0.002)
    assert at_5K.max_heater_power_W == pytest.approx(0.5)
    assert at_5K.sinusoid_line_power_W == pytest.approx(at_5K.mean_heater_power_W)
    assert at_5K.authority < 1.0 and at_5K.limited_by == "authority"


def test_at_6K_the_heater_cancels_the_line_and_noise_limits(reference_model):
    limit = feedforward_limit(reference_model, 6.0, 50.0, 0.1)
    assert limit.mean_heater_power_W == pytest.approx(0.260, abs=0.002)
    assert limit.authority > 1.0
    assert limit.ptc_periodic_limit_K < 1e-3 * limit.open_line_K
    assert limit.limited_by == "noise" and not limit.authority_limited
    assert limit.predicted_best_residual_K == pytest.approx(limit.noise_floor_K, rel=1e-3)


# ---------------------------------------------------------------------------
# (c)-(e) against the sinusoid, the unconstrained optimum, Pmax, convergence
# ---------------------------------------------------------------------------
def test_limit_beats_the_sinusoid_and_never_the_unconstrained_optimum(reference_model, at_5K):
    assert at_5K.ptc_periodic_limit_K < 0.65 * at_5K.best_sinusoid_K
    for row in limit_sweep(reference_model, "setpoint", [4.5, 5.0, 5.5, 6.5, 7.0], setpoint_K=5.0,
                           heater_resistance_ohm=50.0, max_current_A=0.1):
        assert 0.0 < row.limit.ptc_periodic_limit_K <= row.limit.best_sinusoid_K
    roomy = feedforward_limit(reference_model, 6.0, 500.0, 0.1)       # bounds far from the line's needs
    assert roomy.ptc_periodic_limit_K == pytest.approx(0.0, abs=1e-9)


def test_limit_never_grows_with_the_heater_power(reference_model):
    rows = limit_sweep(reference_model, "max_current", np.linspace(0.06, 0.3, 9), setpoint_K=5.0,
                       heater_resistance_ohm=50.0, max_current_A=0.1)
    limits = [row.limit.whole_periodic_limit_K for row in rows]
    assert all(later <= earlier * (1.0 + 1e-6) for earlier, later in zip(limits, limits[1:]))
    assert limits[0] > 1.5 * limits[-1]


def test_converged_in_phase_points_and_harmonics(reference_model, at_5K):
    coarse = feedforward_limit(reference_model, 5.0, 50.0, 0.1, phase_points=128, certify=False)
    fine = feedforward_limit(reference_model, 5.0, 50.0, 0.1, phase_points=1024, certify=False)
    assert coarse.ptc_periodic_limit_K == pytest.approx(fine.ptc_periodic_limit_K, rel=1e-3)
    assert at_5K.ptc_periodic_limit_K == pytest.approx(fine.ptc_periodic_limit_K, rel=2e-4)
    more = feedforward_limit(reference_model, 5.0, 50.0, 0.1, harmonics=24, certify=False)
    assert more.whole_periodic_limit_K <= at_5K.whole_periodic_limit_K
    assert more.ptc_periodic_limit_K == pytest.approx(at_5K.ptc_periodic_limit_K, rel=2e-3)


# ---------------------------------------------------------------------------
# delay, bounds, noise, errors
# ---------------------------------------------------------------------------
def test_a_delay_only_rotates_the_waveform_in_continuous_time(reference_model):
    base = feedforward_limit(reference_model, 5.0, 50.0, 0.1, measure="continuous", certify=False)
    late = feedforward_limit(reference_model, 5.0, 50.0, 0.1, measure="continuous", heater_delay_s=0.037,
                             certify=False)
    assert late.ptc_periodic_limit_K == pytest.approx(base.ptc_periodic_limit_K, rel=1e-4)   # bounds on a grid
    sampled = feedforward_limit(reference_model, 5.0, 50.0, 0.1, heater_delay_s=0.03, certify=False)
    dead = feedforward_limit(reference_model.with_effects(dead_time=DeadTime(0.03)), 5.0, 50.0, 0.1, certify=False)
    assert dead.ptc_periodic_limit_K == pytest.approx(sampled.ptc_periodic_limit_K, rel=1e-9)


def test_waveform_stays_within_the_heater_and_keeps_the_mean(reference_model, at_5K):
    for limit in (at_5K, feedforward_limit(reference_model.with_effects(heater_nonlinearity=HeaterNonlinearity(0.4)),
                                           5.0, 17.0, 0.1, certify=False)):
        assert limit.waveform_power_w.min() >= 0.0
        assert limit.waveform_power_w.max() <= limit.max_heater_power_W
    assert at_5K.waveform_power_w.mean() == pytest.approx(at_5K.mean_heater_power_W, rel=1e-9)
    assert at_5K.waveform_power_w.min() == pytest.approx(0.0, abs=1e-4)      # P >= 0 binds at 5 K
    assert at_5K.largest_line_power_W == pytest.approx(largest_fundamental(0.113, 0.0, 0.5), rel=1e-2)


def test_noise_floor_formula_against_monte_carlo():
    sigma, readings = 20e-6, 750
    generator = np.random.default_rng(1)
    time_s = np.arange(readings) * PERIOD_S
    phase = 10.83 * time_s
    columns = [np.ones(readings)]
    for order in range(1, 7):
        columns += [np.cos(order * phase), np.sin(order * phase)]
    fit = np.linalg.pinv(np.array(columns).T)
    estimates = fit @ generator.normal(0.0, sigma, (readings, 4000))
    amplitude = math.sqrt(np.mean(np.sum(estimates[1:] ** 2, axis=0)))
    assert amplitude == pytest.approx(noise_floor_K(sigma, readings * PERIOD_S, PERIOD_S), rel=0.05)


@pytest.mark.parametrize("arguments, message", [
    ((4.0, 50.0, 0.1), "cannot cool"),
    ((8.0, 50.0, 0.1), "more than the heater's 500 mW"),
    ((5.0, -50.0, 0.1), "heater resistance must be a number > 0"),
    ((5.0, 50.0, 0.0), "current limit must be a number > 0"),
])
def test_refuses_what_has_no_limit(reference_model, arguments, message):
    with pytest.raises(FeedforwardLimitError, match=message):
        feedforward_limit(reference_model, *arguments, certify=False)


# ---------------------------------------------------------------------------
# (f) the command
# ---------------------------------------------------------------------------
def test_command_prints_the_table(capsys):
    assert main(["feedforward-limit"]) == 0
    text = capsys.readouterr().out
    for words in ("50 ohm, 0.1 A", "mean heater power (balance)   112.9 mW", "line power needed", "authority",
                  "open line (no feedforward)    1.730 mK", "best sinusoid", "limit (best waveform)",
                  "limit per harmonic 1-6", "limited by                    authority", "setpoint:",
                  "heater resistance:", "current limit:", "out of reach"):
        assert words in text


def test_command_json(capsys):
    assert main(["feedforward-limit", "--setpoint", "5", "--heater-ohm", "17", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["setpoint_K"] == 5.0 and summary["heater_resistance_ohm"] == 17.0
    assert len(summary["limit_harmonics_K"]) == 6 and summary["limited_by"] in ("authority", "noise")
    assert set(summary["sweeps"]) == {"setpoint", "heater_resistance", "max_current"}
    assert len(summary["waveform"]["heater_power_W"]) == summary["phase_points"]


@pytest.mark.parametrize("arguments, message", [
    (["--heater-ohm", "-5"], "--heater-ohm: must be > 0"),
    (["--max-current", "x"], "expected a number"),
    (["--setpoint", "9"], "more than the heater's"),
    (["--setpoint", "4"], "cannot cool"),
    (["--model", "no/such/model.yaml"], "no/such/model.yaml"),
])
def test_command_refuses_bad_input(capsys, arguments, message):
    try:
        status = main(["feedforward-limit", *arguments])
    except SystemExit as stop:               # argparse's own errors
        status = stop.code
    assert status == 2
    assert message in capsys.readouterr().err
