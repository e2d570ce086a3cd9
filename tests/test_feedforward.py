"""The feedforward locked to the cooler: phase tracking, estimation, the heater's bounds, the loop.

Closed-loop runs use the offline simulation (cryod.control.closed_loop, the
daemon's own regulator) on virtual time; each figure is checked against the
physics (the computed limit, PI alone), not against a recorded number.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from cryod.cooler.phase import CoolerPhaseTracker
from cryod.control.feedforward.bounded_waveform import best_bounded_waveform, waveform_values
from cryod.control.feedforward import FeedforwardSettings, FeedforwardTerm, SynchronousEstimator
from cryod.control.feedforward.harmonic_plant import line_at_harmonics, plant_at_harmonics
from cryod.control.pi import PiGains
from cryod.model import CryostatPlant
from cryod.model.dynamics import flange_transfer_functions
from cryod.model.parameters import SensorLag
from cryod.cooler.periodic import periodic_amplitudes
from cryod.control.closed_loop import Segment, run_program
from tests.feedforward_ticks import feed

OMEGA = 10.83
PERIOD = 0.08
GAINS = PiGains(10.0, 0.2)


# ---------------------------------------------------------------------------
# the cooler's phase
# ---------------------------------------------------------------------------
def track(phase_of, duration_s=60.0, amplitude_of=None, irregular=True, noise_K=3e-4, seed=1):
    generator = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, PERIOD) + 0.01
    if irregular:                                   # every third reading 20 ms later (NORMal autozero)
        t = t + np.where(np.arange(t.size) % 3 == 0, 0.02, 0.0)
    truth = phase_of(t)
    amplitude = 0.12 if amplitude_of is None else amplitude_of(t)
    values = 3.34 + amplitude * np.cos(truth) + 0.002 * np.cos(2 * truth + 1.0) + noise_K * generator.normal(size=t.size)
    tracker = CoolerPhaseTracker(OMEGA)
    states = [tracker.update(time_s, value) for time_s, value in zip(t, values)]
    error = np.angle(np.exp(1j * (np.array([s.phase_rad for s in states]) - truth)))
    locked = np.array([s.locked for s in states])
    return t, error, locked, states


@pytest.mark.parametrize("offset", [-0.02, 0.0, 0.02])
def test_tracker_locks_within_10_s_at_a_frequency_2_percent_off(offset):
    t, error, locked, states = track(lambda t: OMEGA * (1 + offset) * t + 2.0)
    assert locked.any() and t[np.argmax(locked)] < 10.0
    assert np.sqrt(np.mean(error[t > 15.0] ** 2)) < 3e-3
    assert states[-1].frequency_rad_s == pytest.approx(OMEGA * (1 + offset), abs=3e-3)


def test_tracker_follows_a_wandering_cooler_and_a_phase_jump():
    wander = 0.02 * OMEGA
    t, error, locked, _ = track(lambda t: OMEGA * t - wander * 600.0 / (2 * math.pi) * np.cos(2 * math.pi * t / 600.0)
                                + np.where(t > 900.0, 2.5, 0.0), duration_s=1200.0)
    steady = (t > 20.0) & ((t < 900.0) | (t > 910.0))
    assert np.max(np.abs(error[steady])) < 0.02 and locked[steady].all()
    assert np.max(np.abs(error[t > 905.0])) < 0.05                     # the restart pulled in within 5 s


def test_tracker_drops_the_lock_when_the_oscillation_goes():
    t, _, locked, _ = track(lambda t: OMEGA * t, amplitude_of=lambda t: np.where(t > 40.0, 0.0, 0.12))
    assert locked[(t > 20.0) & (t < 40.0)].all()
    assert not locked[t > 42.0].any()


def test_tracker_uses_each_readings_own_instant():
    """With readings 20 ms late every third tick and treated as on time, the phase would be off by 0.22 rad."""
    _, error, _, _ = track(lambda t: OMEGA * t, irregular=True)
    assert np.max(np.abs(error[20 * 12:])) < 0.01


def test_tracker_steps_over_readings_that_are_not_numbers_the_first_ones_too():
    """A T5 reading that is not a number (a gap in a record) is stepped over wherever it comes: T5's mean is
    followed from the first reading that is one, and the tracker locks as without the gap."""
    t = np.arange(0.0, 30.0, PERIOD) + 0.01
    values = 3.34 + 0.12 * np.cos(OMEGA * t)
    values[:5] = np.nan
    tracker = CoolerPhaseTracker(OMEGA)
    states = [tracker.update(time_s, value) for time_s, value in zip(t, values)]
    error = np.angle(np.exp(1j * (np.array([s.phase_rad for s in states]) - OMEGA * t)))
    assert states[-1].locked and states[-1].amplitude_K == pytest.approx(0.12, rel=0.01)
    assert np.max(np.abs(error[t > 20.0])) < 0.01


# ---------------------------------------------------------------------------
# the plant as the loop samples it, the estimator
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("order, delay_s", [(1, 0.0), (5, 0.0), (1, 0.035), (5, 0.035)])
def test_sampled_plant_matches_the_simulated_cryostat(reference_model, order, delay_s):
    """A held heater waveform at harmonic n, set delay_s after each sample, seen in T2's samples."""
    quiet = reference_model.with_ptc(ptc_stage_amplitude_K=0.0)
    plant = CryostatPlant(quiet, 0.0, 0.26)
    times, flange = [], []
    for k in range(int(900 / PERIOD)):
        time_s = k * PERIOD
        plant.advance_to(time_s)
        times.append(time_s)
        flange.append(plant.temperatures()[0])
        setting = time_s + delay_s
        plant.set_heater_power(0.26 + 0.1 * math.cos(order * OMEGA * (setting + PERIOD / 2)), setting)
    times, flange = np.array(times), np.array(flange)
    late = times > 500.0
    angle = order * OMEGA * times[late]
    columns = np.column_stack([np.ones(late.sum()), times[late], np.cos(angle), -np.sin(angle)])
    solution = np.linalg.lstsq(columns, flange[late], rcond=None)[0]
    measured = (solution[2] + 1j * solution[3]) / 0.1
    expected = complex(plant_at_harmonics(quiet, [order], PERIOD, delay_s)[0])
    assert abs(measured - expected) < 1e-3 * abs(expected)
    if order == 5:       # above half the sampling rate the hold's folded images count: far from G(j 5 w)
        continuous = flange_transfer_functions(quiet)[0].frequency_response(5 * OMEGA)
        assert abs(expected) > 1.4 * abs(continuous)


def test_estimator_separates_the_line_from_the_plant_correction():
    generator = np.random.default_rng(0)
    estimator = SynchronousEstimator(2)
    line = np.array([1e-3 * np.exp(0.5j), 2e-4])
    correction = np.array([0.44 * np.exp(-0.82j), 0.8 * np.exp(0.3j)])
    for k in range(5000):
        t = k * PERIOD
        effect = np.array([1.5e-3 * np.exp(1j * (1.0 + 0.01 * t)), 3e-4 * np.exp(-0.02j * t)]) * min(t / 60.0, 1.0)
        value = 5.0 + 1e-5 * t + np.real(np.sum((line + correction * effect) * np.exp(1j * np.arange(1, 3) * OMEGA * t)))
        estimator.add(OMEGA * t, value + 2e-5 * generator.normal(), effect)
    assert np.abs(estimator.correction - correction) == pytest.approx([0, 0], abs=0.05)
    assert np.abs(estimator.line - line) == pytest.approx([0, 0], abs=3e-5)


# ---------------------------------------------------------------------------
# the term on its own: fade, lock loss, switching
# ---------------------------------------------------------------------------
def test_the_waveform_fades_in_and_out_with_the_lock_and_on_command(reference_model):
    term = FeedforwardTerm(FeedforwardSettings(model=reference_model, fade_time_s=5.0), 0.5)
    term.start(None, 0.113)
    feed(term, 40.0)
    assert term.scale == 1.0 and np.any(term.coefficients)
    peak = float(np.max(np.abs(waveform_values(term.coefficients + term.probe, 0.0, 128))))
    term.switch(False)
    off = feed(term, 10.0, 40.0)
    assert term.scale == 0.0 and np.all(off[-20:] == 0.0)
    envelope = peak * np.clip(1.0 - PERIOD * np.arange(1, off.size + 1) / 5.0, 0.0, 1.0)
    assert np.all(np.abs(off) <= envelope + 1e-3)          # fades over 5 s, no jump to 0 W
    term.switch(True)
    feed(term, 15.0, 50.0)                                  # locks again (about 6 s), then fades in
    assert term.scale == 1.0
    lost = feed(term, 10.0, 65.0, cooler=False)             # the cooler stops: the lock goes, the waveform fades
    assert not term.phase.locked and term.scale == 0.0 and np.all(lost[-10:] == 0.0)


def test_the_status_is_worded_from_a_snapshot_that_does_not_change_after(reference_model):
    """``cryod ctl feedforward status``'s words come from a snapshot the loop's thread takes: worded later, on
    another thread, they are the words of the instant it was taken, whatever the term has done since."""
    from cryod.control.feedforward.status_text import status_text

    term = FeedforwardTerm(FeedforwardSettings(model=reference_model), 0.5)
    term.start(None, 0.113)
    feed(term, 40.0)
    snapshot, then = term.status_snapshot(), term.describe()
    assert status_text(snapshot) == then
    with pytest.raises(ValueError):                             # its arrays are its own, read-only copies
        snapshot.played_W[0] = 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        snapshot.scale = 0.0
    term.switch(False)
    feed(term, 10.0, 40.0)
    assert status_text(snapshot) == then and term.describe() != then
    assert then.startswith("feedforward on, waveform at 100 %") and term.describe().startswith("feedforward off")
    term.close()


@pytest.mark.parametrize("harmonics", [4, 8])
def test_a_reload_with_another_number_of_harmonics_keeps_the_waveform_and_goes_on(reference_model, harmonics):
    """Fewer or more harmonics on a reload: the waveform keeps the ones both have, the learning starts again
    with the new number, and the loop goes on (what the readings answer is taken at the new number too)."""
    settings = FeedforwardSettings(model=reference_model)
    term = FeedforwardTerm(settings, 0.5)
    term.start(None, 0.113)
    feed(term, 40.0)
    kept = term.coefficients[:min(harmonics, 6)].copy()
    term.reconfigure(dataclasses.replace(settings, harmonics=harmonics), 0.5)
    assert np.array_equal(term.coefficients[:min(harmonics, 6)], kept) and term.coefficients.size == harmonics
    outputs = feed(term, 30.0, 40.0)
    assert np.all(np.isfinite(outputs)) and term.scale == 1.0 and term.phase.locked
    assert len(term.learned_plant.model) == harmonics
    term.close()


def test_a_reload_keeps_what_was_learned(reference_model):
    settings = FeedforwardSettings(model=reference_model)
    term = FeedforwardTerm(settings, 0.5)
    term.start(None, 0.113)
    feed(term, 60.0)
    learned = term.coefficients.copy()
    term.reconfigure(dataclasses.replace(settings, learning_gain=0.2), 0.5)
    assert np.array_equal(term.coefficients, learned) and term.phase.locked and term.scale == 1.0


# ---------------------------------------------------------------------------
# closed loop on the simulated cryostat
# ---------------------------------------------------------------------------
def closed_loop(model, setpoint_K, controller_model=None, duration_s=900.0, feedforward=True, heater_max_w=0.5):
    settings = FeedforwardSettings(enabled=feedforward, model=controller_model or model)
    return run_program(model, [Segment(0.0, setpoint_K=setpoint_K)], duration_s, gains=GAINS,
                       heater_max_w=heater_max_w, seed=1, more_terms=(("feedforward", settings),))


def periodic(run, from_s=600.0):
    amplitudes = periodic_amplitudes(run.time_s, run.flange_K, run.time_s, run.ptc_stage_K, OMEGA,
                                     window_start_s=from_s)
    return float(np.sqrt(np.sum(amplitudes ** 2)))


def best_band_limited(model, setpoint_K, heater_max_w=0.5, harmonics=16):
    """The least synchronous T2 any waveform of up to 16 harmonics can leave (for the mean the setpoint needs)."""
    orders = np.arange(1, harmonics + 1)
    plant, line = plant_at_harmonics(model, orders, PERIOD), line_at_harmonics(model, harmonics)
    mean = (setpoint_K - model.operating_point.flange_temperature_K) / flange_transfer_functions(model)[0].dc_gain
    best = best_bounded_waveform(line, plant, mean, 0.0, heater_max_w, phase_points=512)
    return float(np.sqrt(np.sum(np.abs(line + plant * best) ** 2)))


@pytest.fixture(scope="module")
def pi_alone_5K(reference_model):
    return closed_loop(reference_model, 5.0, feedforward=False)


@pytest.fixture(scope="module")
def feedforward_5K(reference_model):
    return closed_loop(reference_model, 5.0)


def test_at_5_K_it_reaches_the_physical_limit_well_beyond_the_sinusoids_cap(feedforward_5K, pi_alone_5K,
                                                                             reference_model):
    limit = best_band_limited(reference_model, 5.0)
    achieved = periodic(feedforward_5K)
    assert achieved < periodic(pi_alone_5K) / 3.0          # a sinusoid around 113 mW: about 1.9 times at most
    assert achieved < 1.05 * limit


def test_the_waveform_stays_within_the_heaters_bounds_and_pi_keeps_the_mean(feedforward_5K, pi_alone_5K):
    late = feedforward_5K.time_s > 300.0
    heater = feedforward_5K.heater_w[late]
    assert heater.min() > 0.0 and heater.max() < 0.5
    assert np.mean(heater) == pytest.approx(np.mean(pi_alone_5K.heater_w[late]), rel=0.01)
    assert np.mean(feedforward_5K.flange_K[feedforward_5K.time_s > 600.0]) == pytest.approx(5.0, abs=2e-5)


def test_pi_does_not_chase_the_line(feedforward_5K, pi_alone_5K):
    def line_in(values, run):
        late = run.time_s > 600.0
        angle = run.control["ff_phase_rad"][late]
        columns = np.column_stack([np.ones(late.sum()), np.cos(angle), np.sin(angle)])
        solution = np.linalg.lstsq(columns, values[late], rcond=None)[0]
        return math.hypot(solution[1], solution[2])

    with_feedforward = line_in(feedforward_5K.control["pi_proportional_W"], feedforward_5K)
    assert with_feedforward < 0.05 * GAINS.proportional_w_per_K * 1.7e-3         # Kp x the line: 17 mW


@pytest.fixture(scope="module")
def feedforward_6K(reference_model):
    return closed_loop(reference_model, 6.0)


def test_at_6_K_it_removes_the_line(feedforward_6K):
    assert periodic(feedforward_6K) < 1.73e-3 / 100.0


#: The default run keeps a model too weak (the cryostat twice as strong) and a cryostat lagging more than its model;
#: a model too strong and one that expects more lag than there is are ``slow``.
@pytest.mark.parametrize("gain, lag_deg", [pytest.param(0.5, 0.0, marks=pytest.mark.slow), (2.0, 0.0), (1.0, 60.0),
                                           pytest.param(1.0, -60.0, marks=pytest.mark.slow)])
def test_a_wrong_model_still_converges(reference_model, gain, lag_deg):
    """The controller's model off by 0.5-2x in gain or +-60 degrees at the line: the correction is learned."""
    lag_s = math.tan(math.radians(abs(lag_deg))) / OMEGA
    scaled = dataclasses.replace(reference_model, heater_to_flange=dataclasses.replace(
        reference_model.heater_to_flange, numerator=tuple(gain * c for c in reference_model.heater_to_flange.numerator)))
    if lag_deg > 0:        # the cryostat lags more than the controller thinks
        cryostat, controller = reference_model.with_effects(sensor_lag=SensorLag(lag_s)), reference_model
    elif lag_deg < 0:      # the controller thinks it lags more than it does
        cryostat, controller = reference_model, reference_model.with_effects(sensor_lag=SensorLag(lag_s))
    else:
        cryostat, controller = scaled, reference_model
    achieved = periodic(closed_loop(cryostat, 6.0, controller_model=controller))
    assert achieved < max(1.15 * best_band_limited(cryostat, 6.0), 20e-6)


def test_no_windup_while_the_heater_has_no_room(reference_model):
    """A setpoint the heater cannot hold (PI at R I_max^2 for 10 minutes) leaves no room for a waveform;
    when the setpoint comes back within reach the waveform returns without a jump and converges."""
    settings = FeedforwardSettings(model=reference_model)
    run = run_program(reference_model, [Segment(0.0, setpoint_K=5.6), Segment(600.0, setpoint_K=5.0)], 1200.0,
                      gains=GAINS, heater_max_w=0.18, seed=2, more_terms=(("feedforward", settings),))
    held = (run.time_s > 60.0) & (run.time_s < 600.0)
    assert np.all(run.heater_w[held] <= 0.18) and np.mean(run.heater_w[held] == 0.18) > 0.9
    assert np.max(np.abs(run.control["ff_W"][held])) < 0.02          # no room: (almost) no waveform
    after = run.time_s > 600.0
    assert np.max(np.abs(np.diff(run.control["ff_W"][after]))) < 0.18   # no step beyond the heater's range
    limit = best_band_limited(reference_model, 5.0, heater_max_w=0.18)
    assert periodic(run, from_s=1000.0) < 1.15 * limit


def test_at_6_K_the_waveform_stays_below_the_heaters_maximum(feedforward_6K):
    run = feedforward_6K
    late = run.time_s > 300.0
    assert run.heater_w[late].max() < 0.5 and run.heater_w[late].max() > 0.45     # it uses the room it has


# ---------------------------------------------------------------------------
# a heater held at its bounds (the paper's 17 ohm heater)
# ---------------------------------------------------------------------------
def test_the_power_held_back_is_followed_as_the_cryostat_answers_it(reference_model):
    """UnplayedPower against the simulated cryostat: two records, one with the power asked, one with it
    held at 170 mW; their difference at every reading is what UnplayedPower says it is."""
    from cryod.control.feedforward.unplayed_power import UnplayedPower
    from cryod.model.dynamics import simulate
    t = np.arange(0.0, 60.0, PERIOD)
    setting = t + 0.0325                                        # the heater set 32.5 ms after the readings
    asked = 0.113 + 0.12 * np.cos(OMEGA * t) + 0.03 * np.cos(2 * OMEGA * t + 1.0)
    played = np.minimum(asked, 0.17)
    difference = (simulate(reference_model, t, played, heater_change_s=setting, initial_heater_power_w=0.113).flange_K
                  - simulate(reference_model, t, asked, heater_change_s=setting, initial_heater_power_w=0.113).flange_K)
    unplayed = UnplayedPower(reference_model)
    predicted = []
    for time_s, change_s, power_asked, power_played in zip(t, setting, asked, played):
        predicted.append(unplayed.at(time_s))
        unplayed.set(change_s, power_played - power_asked)
    assert np.max(np.abs(difference)) > 50e-6                   # clipping moves T2 by tens of uK
    assert np.max(np.abs(np.array(predicted) - difference)) < 1e-3 * np.max(np.abs(difference))


def test_a_heater_held_at_its_bounds_does_not_stop_the_learning(reference_model, monkeypatch):
    """17 ohm at 100 mA (170 mW for a mean of 113 mW at 5 K) with the paper's Kp 80 W/K: the total is
    held at a bound on a large share of the ticks; the estimator still takes every reading (T2 as if
    the heater had played what was asked; only those just after a change of the waveform are left out),
    learns a controller model 0.7x too weak and reaches the limit."""
    from cryod.control.feedforward.learning_worker import LearningWorker
    taken = []
    original = LearningWorker.reading
    monkeypatch.setattr(LearningWorker, "reading", lambda self, *values: (taken.append(1), original(self, *values)))
    weak = dataclasses.replace(reference_model, heater_to_flange=dataclasses.replace(
        reference_model.heater_to_flange, numerator=tuple(0.7 * c for c in reference_model.heater_to_flange.numerator)))
    settings = FeedforwardSettings(model=weak)
    run = run_program(reference_model, [Segment(0.0, setpoint_K=5.0)], 900.0, gains=PiGains(80.0, 4.0),
                      heater_max_w=0.17, seed=1, more_terms=(("feedforward", settings),))
    late = run.time_s > 300.0
    held = (run.heater_w[late] <= 0.0) | (run.heater_w[late] >= 0.17)
    assert np.mean(held) > 0.1
    locked = int(np.sum(run.control["ff_locked"] == 1.0))
    # all but the first second after the lock and the half second after each change of the waveform (every 2 s)
    changes = locked * PERIOD / 2.0
    assert len(taken) >= locked - int(1.0 / PERIOD) - 2 - changes * math.ceil(0.5 / PERIOD)
    limit = best_band_limited(reference_model, 5.0, heater_max_w=0.17)
    assert periodic(run) < 1.05 * limit
