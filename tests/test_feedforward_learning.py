"""The feedforward learns the cryostat it is on: the plant at each harmonic, the probe, the projection in the
learned plant's metric, the divergence guard, the limit and the words it reports.

Closed-loop runs use the offline simulation (cryod.control.closed_loop, the daemon's own regulator) on
virtual time, started at the mean power the setpoint needs so that the learning starts at once; each
figure is checked against the simulated cryostat's own plant and limit, which the controller (on the
shipped model) does not know.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import pytest

from cryod.control.closed_loop import Segment, run_program
from cryod.control.feedforward.divergence_guard import DivergenceGuard
from cryod.control.feedforward import FeedforwardSettings, FeedforwardTerm, SynchronousEstimator
from cryod.control.feedforward.limit import feedforward_limit, limit_for_plant, mean_heater_power_w
from cryod.control.feedforward.harmonic_plant import line_at_harmonics, plant_at_harmonics
from cryod.control.feedforward.learned_projection import learning_step
from cryod.control.pi import PiGains
from cryod.control.feedforward.plant_learner import MODEL_ERROR, LearnedPlant
from cryod.control.feedforward.plant_probe import ProbeSettings, ProbeState, next_probe
from cryod.model.parameters import DeadTime, CoolerFrequencyDrift, SensorLag
from cryod.records.metrics import periodic_amplitudes
from tests.feedforward_ticks import feed

OMEGA = 10.83
PERIOD = 0.08
GAINS = PiGains(10.0, 0.2)


def cryostat(reference, gain=1.0, lag_s=0.0, dead_time_s=0.0, wander=0.0):
    """The shipped model with the heater's path scaled, a lagging thermometer, a late heater, a wandering cooler."""
    heater = reference.heater_to_flange
    model = dataclasses.replace(reference, heater_to_flange=dataclasses.replace(
        heater, numerator=tuple(gain * c for c in heater.numerator)))
    effects = {}
    if lag_s:
        effects["sensor_lag"] = SensorLag(lag_s)
    if dead_time_s:
        effects["dead_time"] = DeadTime(dead_time_s)
    if wander:
        effects["ptc_frequency_drift"] = CoolerFrequencyDrift(0.0, wander * OMEGA, 900.0)
    return model.with_effects(**effects)


def true_plant(model, orders=(1, 2, 3)):
    """The cryostat's plant as the loop samples it (heater set at the reading), in the feedforward's convention."""
    dead = model.effects.dead_time.heater_to_flange_s if model.effects.dead_time else 0.0
    omega = OMEGA * np.asarray(orders, dtype=float)
    return plant_at_harmonics(model, orders, PERIOD, dead) * np.exp(-1j * omega * dead)


def settled_run(model, controller, setpoint_K, duration_s=600.0, heater_max_w=0.5, seed=1, **settings):
    """A run started at the mean power the setpoint needs on this cryostat, and its feedforward term."""
    terms = []
    original = FeedforwardTerm.__init__

    def keep(self, *arguments):
        original(self, *arguments)
        terms.append(self)

    FeedforwardTerm.__init__ = keep
    try:
        run = run_program(model, [Segment(0.0, setpoint_K=setpoint_K)], duration_s, gains=GAINS,
                          heater_max_w=heater_max_w, seed=seed, initial_heater_power_w=mean_heater_power_w(model, setpoint_K),
                          more_terms=(("feedforward", FeedforwardSettings(model=controller, **settings)),))
    finally:
        FeedforwardTerm.__init__ = original
    return run, terms[0]


def periodic(run, from_s):
    amplitudes = periodic_amplitudes(run.time_s, run.flange_K, run.time_s, run.ptc_stage_K, OMEGA,
                                     window_start_s=from_s)
    return float(np.sqrt(np.sum(amplitudes ** 2)))


def events(run, text):
    return [event for event in run.events if text in event[3]]


# ---------------------------------------------------------------------------
# closed loop: the model's phase at the line off by up to 180 degrees
# ---------------------------------------------------------------------------
#: 150 degrees, between the two that say the difference in words, is ``slow``.
@pytest.mark.parametrize("error_deg", [0.0, 90.0, pytest.param(150.0, marks=pytest.mark.slow), 180.0])
def test_it_learns_the_plant_whatever_the_models_phase_error(reference_model, error_deg):
    """The heater acts late enough to put the cryostat's plant at the line 0 to 180 degrees behind the model's:
    the plant is learned at harmonics 1-3 to within 5 % and 5 degrees or the spread it states (three standard
    deviations), the line cancelled to the noise floor, nothing diverges, and the difference is said in words."""
    model = cryostat(reference_model, dead_time_s=math.radians(error_deg) / OMEGA)
    run, term = settled_run(model, reference_model, 6.0)
    truth = true_plant(model)
    learned = term.learned_plant
    assert learned.learned[:3].all()
    ratio = learned.plant[:3] / truth
    assert np.all(np.abs(np.abs(ratio) - 1.0) < np.maximum(0.05, 3.0 * learned.gain_spread[:3]))
    assert np.all(np.degrees(np.abs(np.angle(ratio))) < np.maximum(5.0, 3.0 * learned.phase_spread_deg[:3]))
    assert abs(abs(ratio[0]) - 1.0) < 0.05 and abs(math.degrees(np.angle(ratio[0]))) < 5.0
    assert periodic(run, 400.0) < 15e-6                                   # PI alone: 1.8 mK; noise floor 3.6 uK
    assert term.divergences == 0 and not events(run, "diverged")
    said = [event for event in events(run, ": re-commission with cryod identify --acquire")
            if event[2] == logging.WARNING and "at the line" in event[3]]
    if error_deg >= 90.0:
        words = term.learned_plant.difference(0)          # at 180 degrees, later and earlier are the same
        assert any(f"{180 - abs(180 - angle):.0f} degrees {'later' if angle <= 180 else 'earlier'} than the model "
                   f"at the line" in words for angle in error_deg + np.arange(-3, 4))
        assert said and words in said[-1][3] and words in term.describe()
    else:
        assert not said
    assert run.control["ff_limit_from"][-1] == "learned"


def test_at_the_bounds_it_reaches_the_limit_of_the_cryostat_it_is_on(reference_model):
    """A heater path 0.6x the model's, a lagging thermometer and a late heater: 6 K needs 433 mW of the 500 mW
    heater, no waveform can cancel the line, and the projection in the learned plant's metric finds the
    constrained optimum of this cryostat; the reported limit is this cryostat's, not the model's."""
    model = cryostat(reference_model, gain=0.6, lag_s=0.1, dead_time_s=0.02)
    run, term = settled_run(model, reference_model, 6.0)
    limit = feedforward_limit(model, 6.0, 0.5, 1.0, PERIOD, certify=False)
    assert limit.limited_by == "authority"
    assert periodic(run, 400.0) < 1.1 * limit.ptc_periodic_limit_K
    model_limit = feedforward_limit(reference_model, 6.0, 0.5, 1.0, PERIOD, certify=False)
    assert model_limit.ptc_periodic_limit_K < 0.1 * limit.ptc_periodic_limit_K     # the model says: cancelled
    assert term.physical_limit.ptc_periodic_limit_K == pytest.approx(limit.ptc_periodic_limit_K, rel=0.1)
    assert "from the learned plant" in term.describe()
    assert events(run, "weaker and")


def test_a_setpoint_the_model_says_is_out_of_reach_gets_its_limit_from_what_was_learned(reference_model):
    """A heater path 2x the model's and a 170 mW heater: by the model 6 K needs 260 mW and is out of reach, on
    this cryostat it needs 130 mW; the limit reported is this cryostat's."""
    model = cryostat(reference_model, gain=2.0)
    run, term = settled_run(model, reference_model, 6.0, heater_max_w=0.17)
    limit = feedforward_limit(model, 6.0, 0.17, 1.0, PERIOD, certify=False)
    assert term.limits.model_limit is None and run.control["ff_limit_from"][-1] == "learned"
    assert term.physical_limit.ptc_periodic_limit_K == pytest.approx(limit.ptc_periodic_limit_K, rel=0.1)
    assert periodic(run, 400.0) < 1.1 * limit.ptc_periodic_limit_K


def test_with_a_wandering_cooler(reference_model):
    """The cooler's frequency wandering by +-1.5 % over 15 minutes on a cryostat 2x stronger and lagging."""
    model = cryostat(reference_model, gain=2.0, lag_s=0.1, wander=0.015)
    run, term = settled_run(model, reference_model, 5.0)
    limit = feedforward_limit(model, 5.0, 0.5, 1.0, PERIOD, certify=False)
    achieved = periodic(run, 400.0)
    assert achieved < 1.1 * limit.ptc_periodic_limit_K
    assert term.divergences == 0


# ---------------------------------------------------------------------------
# the divergence guard, on a plant the learning cannot follow
# ---------------------------------------------------------------------------
def test_a_plant_it_cannot_follow_is_caught_faded_out_and_reset(reference_model):
    """Once learned, the plant turns by 180 degrees at a stroke and keeps turning (a turn a minute): each
    step now moves the line the wrong way. The guard trips, the waveform fades out, the plant goes back to
    the model's, the reason is said, and the learning tries again later."""
    term = FeedforwardTerm(FeedforwardSettings(model=reference_model, retry_after_s=30.0), 0.5)
    term.start(None, 0.113)
    feed(term, 90.0)
    assert term.learned_plant.learned[0] and term.scale == 1.0 and term.divergences == 0
    model_plant = term.plant.copy()
    said = []
    for second in range(90, 240):
        turned = model_plant * np.exp(1j * (math.pi + 2.0 * math.pi * (second - 90) / 60.0))
        feed(term, 1.0, start_s=float(second), plant=turned)
        said += list(term.take_events())
        if term.divergences and term.scale == 0.0:
            break
    assert term.divergences == 1 and term.scale == 0.0
    warnings = [text for level, text in said if level == logging.WARNING and "diverged" in text]
    assert warnings and "fades out" in warnings[0] and "reset to the model" in warnings[0]
    feed(term, 2.5, start_s=float(second + 1), plant=model_plant)
    assert not term.learned_plant.learned.any() and not np.any(term.coefficients)    # the model's again
    assert "starts again in" in term.describe()
    feed(term, 60.0, start_s=float(second + 4), plant=model_plant)                 # after the wait, it learns
    assert term.scale == 1.0 and term.learned_plant.learned[0]


def test_the_guard_trips_on_growth_and_on_worse_than_pi_alone_but_not_on_a_rise_that_stays():
    guard = DivergenceGuard(intervals=5)
    assert not any(guard.observe(value, 1e-3) for value in (30e-6, 125e-6, 142e-6, 144e-6, 146e-6, 146.5e-6))
    guard.clear()
    trips = [guard.observe(value, 1e-3) for value in 20e-6 * 1.5 ** np.arange(8)]
    assert trips[-1] is not None and "grew" in trips[-1]
    guard.clear()
    trips = [guard.observe(1.3e-3, 1e-3) for _ in range(5)]
    assert trips[:4] == [None] * 4 and "above PI alone's" in trips[4]


# ---------------------------------------------------------------------------
# a reload keeps what was learned
# ---------------------------------------------------------------------------
def test_a_reload_keeps_the_learned_plant_even_with_another_controller_model(reference_model):
    """Learning on a plant 0.6x the model's and 70 degrees late; a reload changing the learning gain keeps
    the plant and the waveform; one changing the controller's model keeps the plant learned in kelvin per
    watt (the cryostat did not change), though its ratio to the new model differs."""
    true = plant_at_harmonics(reference_model, np.arange(1, 7), PERIOD) * 0.6 * np.exp(-1.22j)
    settings = FeedforwardSettings(model=reference_model)
    term = FeedforwardTerm(settings, 0.5)
    term.start(None, 0.113)
    feed(term, 120.0, plant=true)
    learned = term.learned_plant
    assert learned.learned[0] and abs(learned.plant[0] / true[0] - 1.0) < 0.05
    waveform = term.coefficients.copy()
    term.reconfigure(dataclasses.replace(settings, learning_gain=0.3), 0.5)
    assert np.array_equal(term.coefficients, waveform) and term.learned_plant is learned
    stronger = dataclasses.replace(reference_model, heater_to_flange=dataclasses.replace(
        reference_model.heater_to_flange, numerator=tuple(1.5 * c for c in reference_model.heater_to_flange.numerator)))
    term.reconfigure(dataclasses.replace(settings, model=stronger), 0.5)
    feed(term, 4.0, start_s=120.0, plant=true)
    again = term.learned_plant
    assert again.learned[0] and abs(again.plant[0] / learned.plant[0] - 1.0) < 0.02
    assert abs(again.gain_ratio[0] * 1.5 - learned.gain_ratio[0]) < 0.02
    term.close()


# ---------------------------------------------------------------------------
# a zone change: the learned plant starts again from the zone's model
# ---------------------------------------------------------------------------
def test_entering_another_zone_starts_the_learned_plant_again_from_the_zones_model(reference_model):
    """A cryostat whose heater reaches T2 0.8x as strongly as the shipped model says; zone 1 (to 5.2 K) has the
    shipped model as the feedforward's, zone 2 this cryostat's own. Learned in zone 1 (0.8 x its model), the
    plant is dropped when the setpoint moves into zone 2 (a plant learned at one operating point is not the
    plant at another), said as an event, and learned again there against zone 2's model (1.0 x)."""
    from cryod.control.zones import Zone, ZoneTable

    model = cryostat(reference_model, gain=0.8)
    zones = ZoneTable((Zone(5.2, GAINS), Zone(20.0, GAINS, feedforward_model=model, feedforward_model_source="zone-2.yaml")))
    run = run_program(model, [Segment(0.0, setpoint_K=5.0), Segment(240.0, setpoint_K=5.4)], 480.0, gains=GAINS,
                      heater_max_w=0.5, seed=1, initial_heater_power_w=mean_heater_power_w(model, 5.0), zones=zones,
                      more_terms=(("feedforward", FeedforwardSettings(model=reference_model)),))
    entered = events(run, "zone 2 entered")
    assert len(entered) == 1 and 240.0 <= entered[0][0] < 241.0
    assert "learning starts again from the zone's model (zone-2.yaml)" in entered[0][3]
    assert [event[0] > 240.0 for event in events(run, "plant learned at the line")] == [False, True]
    at_the_line = [(event[0], float(event[3].split("harmonic 1: ")[1].split(" ")[0]))
                   for event in events(run, "learned plant: harmonic 1")]
    assert [ratio for time_s, ratio in at_the_line if time_s < 240.0][-1] == pytest.approx(0.8, abs=0.03)
    assert [ratio for time_s, ratio in at_the_line if time_s > 240.0][-1] == pytest.approx(1.0, abs=0.03)


# ---------------------------------------------------------------------------
# warnings said on settled data only
# ---------------------------------------------------------------------------
def _setpoint_changes(model, controller, changes, seed, spacing_s=400.0):
    """A run through ``changes`` setpoint changes between 5.0 and 5.8 K, ``spacing_s`` apart: long enough for T2 to
    settle and for the report's settled time to pass at each."""
    setpoints = [5.0 + 0.2 * ((index * 7) % 5) for index in range(changes + 1)]
    return run_program(model, [Segment(spacing_s * index, setpoint_K=value) for index, value in enumerate(setpoints)],
                       spacing_s * (changes + 1), gains=GAINS, heater_max_w=0.5, seed=seed,
                       initial_heater_power_w=mean_heater_power_w(model, 5.0),
                       more_terms=(("feedforward", FeedforwardSettings(model=controller)),))


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.slow), pytest.param(3, marks=pytest.mark.slow)])
def test_setpoint_changes_on_the_cryostat_the_model_describes_give_no_warning(reference_model, seed):
    """Twenty setpoint changes on the cryostat the controller's model describes: what the learning finds while
    T2 ramps is the transient, and no difference is said."""
    run = _setpoint_changes(reference_model, reference_model, 20, seed)
    assert len(events(run, "learned plant: harmonic 1")) >= 10
    assert events(run, "the heater reaches T2") == [] and events(run, "agrees with the model") == []


def test_a_heater_weaker_than_the_model_is_said_once_with_its_numbers(reference_model):
    """The same changes on a cryostat whose heater reaches T2 0.7x as strongly: said once T2 has settled at
    the first setpoint, as 1.4x weaker at the line; not again at every change."""
    run = _setpoint_changes(cryostat(reference_model, gain=0.7), reference_model, 5, seed=1)
    said = events(run, "the heater reaches T2")
    assert 1 <= len(said) <= 2 and said[0][0] < 400.0
    assert all(text.startswith("the heater reaches T2 1.4x weaker than the model at the line; ")
               and text.endswith(": re-commission with cryod identify --acquire") for _, _, _, text in said)
    assert events(run, "agrees with the model") == []


def _plant_at(gain_ratio, phase_deg=0.0):
    model = np.array([7.36e-3 * np.exp(-2.0j), 4.06e-3 * np.exp(-2.4j)])
    correction = np.full(2, gain_ratio * np.exp(1j * math.radians(phase_deg)))
    return LearnedPlant(model, correction, np.tile(np.eye(2) * 1e-4, (2, 1, 1)))


def _warnings(report):
    return [text for level, text in report.take() if level == logging.WARNING]


def test_a_difference_is_said_once_t2_has_been_at_its_setpoint_and_the_difference_has_held():
    from cryod.control.feedforward.learning_report import DIFFERING_FOR_S, SETTLED_FOR_S, LearningReport

    report = LearningReport()
    for time_s in np.arange(0.0, 600.0, 2.0):                       # ramping: never said, however long
        report.step(time_s, _plant_at(0.7), [], settled=False)
    assert _warnings(report) == []
    for time_s in np.arange(600.0, 600.0 + SETTLED_FOR_S, 2.0):   # settled, not yet for long enough
        report.step(time_s, _plant_at(0.7), [], settled=True)
    assert _warnings(report) == []
    report.step(600.0 + SETTLED_FOR_S, _plant_at(0.7), [], settled=True)
    assert _warnings(report) == ["the heater reaches T2 1.4x weaker than the model at the line; 1.4x weaker at "
                                 "harmonic 2: re-commission with cryod identify --acquire"]
    fresh = LearningReport()                                        # settled, but the difference only just appeared
    for time_s in np.arange(0.0, 400.0, 2.0):
        fresh.step(time_s, _plant_at(0.7 if time_s >= 300.0 else 1.0), [], settled=True)
        if time_s < 300.0 + DIFFERING_FOR_S:
            assert _warnings(fresh) == []
    assert len(_warnings(fresh)) == 1


def test_a_difference_is_said_again_when_the_plant_moved_not_when_its_last_digit_wobbles():
    from cryod.control.feedforward.learning_report import SAY_AGAIN_S, LearningReport

    report = LearningReport()
    wobbling = [0.69, 0.72, 0.67, 0.74] * 100                      # 1.4x, 1.4x, 1.5x, 1.4x weaker ...
    for index, ratio in enumerate(wobbling):
        report.step(2.0 * index, _plant_at(ratio), [], settled=True)
    assert len(_warnings(report)) == 1
    time_s = 2.0 * len(wobbling)
    report.step(time_s, _plant_at(0.5, phase_deg=-40.0), [], settled=True)     # it moved: said again
    assert _warnings(report) == ["the heater reaches T2 2.0x weaker and 40 degrees later than the model at the "
                                 "line; 2.0x weaker and 40 degrees later at harmonic 2: re-commission with cryod "
                                 "identify --acquire"]
    report.step(time_s + SAY_AGAIN_S / 2, _plant_at(0.3), [], settled=True)    # moved again, but too soon
    assert _warnings(report) == []
    for later_s in np.arange(time_s + SAY_AGAIN_S / 2, time_s + 2 * SAY_AGAIN_S, 2.0):
        report.step(later_s, _plant_at(1.0), [], settled=True)                   # agrees again, once that has held
    assert [text for _, text in report.take()] == ["the learned plant agrees with the model within its uncertainty"]


# ---------------------------------------------------------------------------
# the parts
# ---------------------------------------------------------------------------
def test_the_learned_plant_is_used_once_known_better_than_the_models_error_at_any_phase():
    model = np.array([7.36e-3 * np.exp(-2.0j)] * 4)
    correction = np.array([np.exp(1j * math.radians(angle)) for angle in (0.0, 90.0, 179.0, -150.0)])
    tight = np.tile(np.eye(2) * 0.01 ** 2, (4, 1, 1))
    learned = LearnedPlant(model, correction, tight)
    assert learned.learned.all() and np.allclose(learned.plant, model * correction)
    assert learned.phase_deg[2] == pytest.approx(179.0) and learned.phase_deg[3] == pytest.approx(-150.0)
    loose = np.tile(np.eye(2) * (MODEL_ERROR / math.sqrt(2) * 1.01) ** 2, (4, 1, 1))
    assert not LearnedPlant(model, correction, loose).learned.any()
    assert learned.difference(1) == "the heater reaches T2 90 degrees earlier than the model at harmonic 2"
    assert LearnedPlant(model, np.array([1.02, 1.0, 1.0, 1.0]), tight).difference(0) is None    # below what matters


def test_the_estimators_stated_spread_is_what_the_readings_give():
    """The filter works on second differences and would misstate its spread by up to 12x in variance (the
    fundamental) or 2.3x (the third harmonic); corrected, the spread it states matches the spread of its
    estimates over independent noise at every harmonic (within 40 %, and never smaller)."""
    harmonics, estimates, stated = 6, [], []
    for seed in range(24):
        generator = np.random.default_rng(seed)
        estimator = SynchronousEstimator(harmonics)
        for k in range(int(80 / PERIOD)):
            t = k * PERIOD
            effect = 50e-6 * np.exp(1j * (0.5 * math.pi * int(t / 2.0) + np.arange(harmonics)))
            value = 5.0 + 1e-4 * t + float(np.real(np.sum((np.r_[1.7e-3, np.zeros(harmonics - 1)] + effect)
                                                          * np.exp(1j * np.arange(1, harmonics + 1) * OMEGA * t))))
            estimator.add(OMEGA * t, value + 20e-6 * generator.standard_normal(), effect)
            if k % 25 == 24:
                estimator.forget_last()
        estimates.append(estimator.raw_correction.real)
        stated.append(np.sqrt(estimator.learned_plant(np.ones(harmonics), OMEGA).covariance[:, 0, 0]))
    ratio = np.mean(stated, axis=0) / np.std(estimates, axis=0)
    assert np.all(ratio > 0.9) and np.all(ratio < 1.6)


def test_the_probe_takes_one_harmonic_at_a_time_within_its_share_of_the_room():
    model = np.array([7.36e-3 * np.exp(-2.0j), 4.06e-3, 3.21e-3])
    settings = ProbeSettings(amplitude_K=50e-6, precision=0.025, longest_s=10.0, room_share=0.15)
    unknown = LearnedPlant.from_model(model)
    state, probe = next_probe(ProbeState.start(3), unknown, room_w=0.2, interval_s=2.0, settings=settings)
    assert np.count_nonzero(probe) == 1 and probe[0] != 0
    assert abs(probe[0]) == pytest.approx(50e-6 / 7.36e-3)
    state, probe = next_probe(state, unknown, room_w=0.02, interval_s=2.0, settings=settings)
    assert abs(probe[0]) == pytest.approx(0.15 * 0.02)                     # no more than its share
    known_first = LearnedPlant(model, np.ones(3, dtype=complex),
                               np.array([np.eye(2) * 1e-4, np.eye(2), np.eye(2)]))
    state, probe = next_probe(state, known_first, room_w=0.2, interval_s=2.0, settings=settings)
    assert probe[0] == 0 and probe[1] != 0 and probe[2] == 0
    for _ in range(6):                                                       # 10 s at harmonic 2: it gives up
        state, probe = next_probe(state, known_first, room_w=0.2, interval_s=2.0, settings=settings)
    assert state.given_up() == [2] and probe[2] != 0
    known = LearnedPlant(model, np.ones(3, dtype=complex), np.tile(np.eye(2) * 1e-4, (3, 1, 1)))
    state, probe = next_probe(state, known, room_w=0.2, interval_s=2.0, settings=settings)
    assert not np.any(probe) and not any(state.probing)


def test_a_step_aims_only_at_harmonics_whose_plant_is_learned():
    model = np.array([7.36e-3 * np.exp(-2.0j), 4.06e-3 * np.exp(-2.4j)])
    line = np.array([1.7e-3, 0.3e-3], dtype=complex)
    half = LearnedPlant(model, np.ones(2, dtype=complex), np.array([np.eye(2) * 1e-4, np.eye(2)]))
    step = learning_step(np.zeros(2, dtype=complex), line, half, 1.0, base_w=0.26, low_w=0.0, high_w=0.5)
    assert step[0] == pytest.approx(-line[0] / model[0]) and abs(step[1]) < 1e-9
    nothing = learning_step(np.zeros(2, dtype=complex), line, LearnedPlant.from_model(model), 1.0, 0.26, 0.0, 0.5)
    assert not np.any(nothing)


def test_the_limit_for_a_plant_known_at_the_harmonics_is_the_models_limit_for_the_model(reference_model):
    orders = np.arange(1, 13)
    mean = mean_heater_power_w(reference_model, 5.0)
    learned = limit_for_plant(line_at_harmonics(reference_model, 12), plant_at_harmonics(reference_model, orders, PERIOD),
                              mean, 0.5, 5.0, PERIOD, heater_delay_s=0.0, cooler_angular_frequency_rad_s=OMEGA,
                              sensor_noise_rms_K=20e-6)
    modelled = feedforward_limit(reference_model, 5.0, 0.5, 1.0, PERIOD, certify=False)
    assert learned.ptc_periodic_limit_K == pytest.approx(modelled.ptc_periodic_limit_K, rel=1e-3)
    assert learned.authority == pytest.approx(modelled.authority, rel=1e-6)


# ---------------------------------------------------------------------------
# the daemon: status keys, journal and record
# ---------------------------------------------------------------------------
def test_the_daemon_reports_what_it_learned_in_the_record_the_journal_and_its_summary(reference_model, tmp_path):
    """`cryod --simulate` on a cryostat whose heater reaches T2 0.6x as strongly and 90 degrees later at the line
    than the controller's model says: the data log and the journal say so in words, the record keeps the learned
    plant in event lines, ``ff_limit_from`` turns to ``learned`` with ``ff_limit_K`` this cryostat's limit."""
    import io

    from cryod.model.model_file import save_model
    from cryod.records.record import read_record
    from cryod.service.simulation import simulate

    model = cryostat(reference_model, gain=0.6, dead_time_s=math.radians(90.0) / OMEGA)
    path = save_model(model, tmp_path / "cryostat.yaml")
    journal = io.StringIO()
    run = simulate(900.0, 6.0, sim_model=path, seed=2, data_dir=tmp_path / "data", socket=tmp_path / "c.sock",
                   log_stream=journal)
    summary = run.summary
    record = read_record(summary["log_path"])
    said = [text for _, text in record.events if text.startswith("event: feedforward: the heater reaches T2")]
    assert said and "weaker" in said[-1] and "degrees later than the model at the line" in said[-1] \
        and said[-1].endswith("re-commission with cryod identify --acquire")
    assert said[-1][len("event: feedforward: "):] in journal.getvalue()
    assert any(text.startswith("event: feedforward: learned plant: harmonic 1:") for _, text in record.events)
    assert record.columns["ff_limit_from"][-1] == "learned" == summary["feedforward_limit_from"]
    assert record.columns["ff_limit_K"][-1] == pytest.approx(summary["ptc_periodic_limit_K"], rel=0.1)
    assert summary["feedforward_plant"][0]["learned"] and summary["feedforward_plant_differences"]
    assert summary["feedforward_divergences"] == 0
