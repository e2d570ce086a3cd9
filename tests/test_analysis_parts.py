"""The analysis's parts against independent numbers: line, noise, segments, replay, decision rules."""

import math

import numpy as np
import pytest

from cryod.analysis.decision import BaseDiscrepancy, CandidateScore, Gain, decide
from cryod.analysis.noise import white_noise_rms
from cryod.cooler.line import estimate_ptc_line, fit_phase_track, phase_track
from cryod.analysis.record_data import RecordData, fit_block_mask, heater_limit_from_metadata
from cryod.analysis.replay import Replayer
from cryod.analysis.segments import find_segments, find_steps
from cryod.model.transfer_function import first_order_link
from cryod.model import PtcFrequencyDrift, simulate
from cryod.records.record import Record, RecordFormatError
from simulated_hw.measurement_programs import make_record


def _record(columns, metadata=None, source="test"):
    return Record(dict(metadata or {}), {k: np.asarray(v) for k, v in columns.items()}, source=source)


# -- the PTC line in T5 ---------------------------------------------------------
def test_line_frequency_amplitude_phase_and_harmonics_with_jitter():
    generator = np.random.default_rng(4)
    t = np.cumsum(generator.uniform(0.07, 0.09, 12000))
    t -= t[0]
    stage = (3.3 + 0.11 * np.sin(10.61 * t - 2.0) + 0.006 * np.sin(2 * 10.61 * t + 0.4)
             + generator.normal(0.0, 3e-4, t.size))
    line = estimate_ptc_line(t, stage, np.ones((t.size, 1)), orders=(1, 2, 3), significant_only=True)
    assert line.angular_frequency_rad_s == pytest.approx(10.61, abs=1e-5)
    assert line.fundamental.amplitude_K == pytest.approx(0.11, rel=1e-3)
    assert line.fundamental.phase_rad == pytest.approx(-2.0, abs=2e-3)
    assert line.orders == (1, 2)                                   # order 3 is noise: left out
    assert line.components[1].amplitude_K == pytest.approx(0.006, rel=0.02)


@pytest.mark.parametrize("drift", [PtcFrequencyDrift(0.02), PtcFrequencyDrift(0.0, 0.003, 900.0)])
def test_frequency_drift_recovered_from_the_phase(drift):
    t = np.arange(0.0, 3600.0, 0.08)
    phase = 10.83 * t + drift.phase_offset(t)
    stage = 3.34 + 0.12 * np.sin(phase + 1.0) + np.random.default_rng(2).normal(0.0, 3e-4, t.size)
    line = estimate_ptc_line(t, stage, np.ones((t.size, 1)), drift=True)
    assert line.angular_frequency_rad_s == pytest.approx(10.83, abs=1e-4)
    assert line.drift.rate_rad_s_per_hour == pytest.approx(drift.rate_rad_s_per_hour, abs=2e-4)
    assert line.drift.wander_amplitude_rad_s == pytest.approx(drift.wander_amplitude_rad_s, abs=1e-4)
    if drift.wander_amplitude_rad_s:
        assert line.drift.wander_period_s == pytest.approx(drift.wander_period_s, rel=0.02)


def test_phase_track_of_a_steady_line_shows_no_drift():
    t = np.arange(0.0, 1800.0, 0.08)
    stage = 0.12 * np.sin(10.83 * t) + np.random.default_rng(3).normal(0.0, 3e-4, t.size)
    fit = fit_phase_track(phase_track(t, stage, 10.83), 1800.0)
    assert abs(fit.drift.rate_rad_s_per_hour) < 5 * fit.rate_uncertainty_rad_s_per_hour
    assert fit.drift.wander_amplitude_rad_s == 0.0



@pytest.mark.parametrize("rate_rad_s_per_hour", [0.0, 2e-4])
def test_a_heater_waveform_locked_to_the_cooler_is_not_a_frequency_drift(reference_model, rate_rad_s_per_hour):
    """A cooler at a fixed frequency and a heater waveform at its line fading in over 300 s to 0.1 W, as the
    feedforward's does: through the heater's path it turns T5's phase at the line by about a milliradian, which
    the phase track of T5 as read takes for a drift at 5 sigma. Tracked in T5 less the model's heater part, the
    drift is within its uncertainty; a real drift of 2e-4 rad/s per hour (0.011 rad of phase over the record)
    is still found."""
    from cryod.analysis.discrepancies import drift_discrepancy

    model = reference_model.with_effects(ptc_frequency_drift=PtcFrequencyDrift(rate_rad_s_per_hour)
                                         if rate_rad_s_per_hour else None)
    omega = model.ptc.angular_frequency_rad_s
    t = np.arange(0.0, 900.0, 0.08)
    heater = 0.12 + 0.1 * np.clip(t / 300.0, 0.0, 1.0) * np.cos(omega * t + 1.0)
    simulated = simulate(model, t, heater, noise=True, seed=1)
    data = RecordData(t, simulated.flange_K, simulated.ptc_stage_K, heater, np.full(t.size, 5.0))
    as_read = fit_phase_track(phase_track(t, simulated.ptc_stage_K, omega), 900.0)
    rate = drift_discrepancy(data, reference_model, omega)[0]
    assert rate.quantity == "PTC line frequency drift rate (rad/s per hour)" and rate.model == 0.0
    if rate_rad_s_per_hour:
        assert rate.measured == pytest.approx(rate_rad_s_per_hour, rel=0.1) and rate.significance > 10.0
    else:
        assert abs(as_read.drift.rate_rad_s_per_hour) > 5.0 * as_read.rate_uncertainty_rad_s_per_hour
        assert rate.significance < 3.0


# -- noise -----------------------------------------------------------------------
@pytest.mark.parametrize("interval", [0.08, 0.2])
def test_noise_floor_ignores_line_and_slow_misfit(interval):
    t = np.arange(0.0, 3600.0, interval)
    noise = np.random.default_rng(1).normal(0.0, 20e-6, t.size)
    misfit = 2e-3 * np.sin(10.83 * t) + 5e-4 * np.sin(3 * 10.83 * t) + 3e-3 * np.exp(-t / 300.0) + 1e-6 * t
    assert white_noise_rms(noise + misfit, interval, 10.83) == pytest.approx(20e-6, rel=0.03)


# -- segments and steps -------------------------------------------------------------
def test_segments_of_the_identification_protocol(reference_model):
    record = make_record(reference_model, "identification", duration_s=1900.0, seed=1)
    columns = record.columns
    segments = find_segments(columns["time_s"], columns["heater_W"], columns["setpoint_K"])
    assert [s.kind for s in segments] == ["hold", "hold", "hold", "modulated", "modulated", "closed loop", "hold",
                                          "hold", "closed loop"]
    assert segments[5].setpoint_K == pytest.approx(5.0)
    assert segments[4].start_s == pytest.approx(segments[3].start_s + 120.0, abs=30.0)   # line, then 2.5 rad/s
    steps = find_steps(columns["time_s"], columns["heater_W"], segments)
    assert [(round(s.before_w, 3), round(s.after_w, 3)) for s in steps] == [(0.0, 0.01), (0.01, 0.03), (0.11, 0.14)]


# -- the record -------------------------------------------------------------------
def test_record_checks_name_what_is_wrong():
    t = np.arange(0.0, 300.0, 0.08)
    good = {"time_s": t, "T2_K": 4.23 + 0 * t, "T5_K": 3.34 + 0 * t, "heater_W": 0 * t, "setpoint_K": np.nan * t}
    RecordData.from_record(_record(good))
    with pytest.raises(RecordFormatError, match="too short"):
        RecordData.from_record(_record({k: v[:100] for k, v in good.items()}))
    bad = dict(good, heater_W=np.where(t > 100, np.nan, 0.0))
    with pytest.raises(RecordFormatError, match="heater_W.*row 1252"):
        RecordData.from_record(_record(bad))
    with pytest.raises(RecordFormatError, match="negative"):
        RecordData.from_record(_record(dict(good, heater_W=0 * t - 1e-3)))


def test_heater_limit_from_metadata():
    assert heater_limit_from_metadata(_record({}, {"heater_resistance_ohm": "50 ohm",
                                                   "heater_current_limit_A": "0.1"})) == pytest.approx(0.5)
    assert heater_limit_from_metadata(_record({}, {"heater_max_W": "0.3"})) == pytest.approx(0.3)
    assert heater_limit_from_metadata(_record({}, {"site": "lab"})) is None


def test_fit_blocks_alternate_and_cover_both_halves():
    t = np.arange(0.0, 3600.0, 0.08)
    mask = fit_block_mask(t)
    assert mask.mean() == pytest.approx(0.5, abs=0.01)
    assert mask[t < 120].all() and not mask[(t >= 120) & (t < 240)].any()


# -- replay -------------------------------------------------------------------------
def test_replay_of_a_pi_record_from_cold_finds_the_settled_power(reference_model):
    """A PI record starts at 0 W with the heater at its limit in the first row: replayed as it happened."""
    record = make_record(reference_model.with_ptc(phase_rad=-1.0), "pi_only", duration_s=600.0, seed=3)
    data = RecordData.from_record(_record(record.columns))
    assert data.heater_w[0] > 0.2
    replayer = Replayer(data, np.ones(data.time_s.size, dtype=bool))
    line = replayer.stage_line(reference_model)
    replayer.settle_from(replayer.replay(reference_model, line))
    assert replayer.initial_heater_power_w == pytest.approx(0.0, abs=2e-3)
    replay = replayer.replay(reference_model, line)
    assert np.std(replay.flange_residual_K) == pytest.approx(20e-6, rel=0.05)
    assert replay.operating_point.flange_temperature_K == pytest.approx(4.23, abs=1e-5)
    assert line.fundamental.phase_rad == pytest.approx(-1.0, abs=1e-3)


def test_replay_is_the_simulator(reference_model):
    t = np.arange(0.0, 900.0, 0.08)
    heater = np.where(t > 300.0, 0.02, 0.0)
    truth = simulate(reference_model, t, heater)
    data = RecordData.from_record(_record({"time_s": t, "T2_K": truth.flange_K, "T5_K": truth.ptc_stage_K,
                                           "heater_W": heater, "setpoint_K": np.nan * t}))
    replayer = Replayer(data, np.ones(t.size, dtype=bool))
    replay = replayer.replay(reference_model, replayer.stage_line(reference_model))
    assert np.max(np.abs(replay.flange_residual_K)) < 1e-8
    assert np.max(np.abs(replay.ptc_stage_residual_K)) < 1e-6      # 1e-5 of the line


# -- link forms ---------------------------------------------------------------------
def test_first_order_link_reproduces_any_gain_at_the_line():
    for value in (2.0 * np.exp(-0.7j), 3.0 * np.exp(0.4j), 1.5 * np.exp(2.5j)):
        link = first_order_link(complex(value), 10.83)
        assert link.frequency_response(10.83) == pytest.approx(complex(value), rel=1e-9)
    lag = first_order_link(5.333 / complex(1.0, 10.83 * 0.1996), 10.83)
    assert lag.denominator == pytest.approx((0.1996, 1.0)) and lag.numerator == pytest.approx((5.333,))


# -- decision rules ---------------------------------------------------------------------
def _score(cause, improvement, distinctness, excess):
    return CandidateScore(cause, 0.0, 0.0, improvement, distinctness, improvement / (2 * math.sqrt(distinctness)),
                          improvement / excess if excess > 0 else 0.0, Gain("m", 2.0, 1.0, 2.0))


def test_decision_rules():
    terms = 40000
    quiet = BaseDiscrepancy(terms, terms + 100.0, 100.0, 100.0 / math.sqrt(2 * terms))
    assert decide(quiet, [_score("dead_time", 90.0, 100.0, 100.0)]).cause == "none"
    loud = BaseDiscrepancy(terms, 3.0 * terms, 2.0 * terms, 2.0 * terms / math.sqrt(2 * terms))
    assert decide(loud, [_score("dead_time", 1.9 * terms, 2.0 * terms, 2.0 * terms),
                         _score("sensor_lag", 1.0 * terms, 2.0 * terms, 2.0 * terms)]).cause == "dead_time"
    partial = decide(loud, [_score("heater_nonlinearity", 0.5 * terms, terms, 2.0 * terms)])
    assert partial.cause == "unexplained" and "25.0 %" in partial.reason
    assert decide(loud, [_score("sensor_lag", -5.0, 100.0, 2.0 * terms)]).cause == "unexplained"


def test_a_tie_goes_to_the_candidate_with_fewer_parameters():
    terms = 40000
    loud = BaseDiscrepancy(terms, 3.0 * terms, 2.0 * terms, 2.0 * terms / math.sqrt(2 * terms))
    scores = [_score("link_dynamics", 1.99 * terms, 2.0 * terms, 2.0 * terms),
              _score("sensor_lag", 1.99 * terms - 10.0, 2.0 * terms, 2.0 * terms)]
    tied = decide(loud, scores, distinctness=lambda a, b: 16.0, parameter_counts={"link_dynamics": 2, "sensor_lag": 1})
    assert tied.cause == "sensor_lag" and "cannot tell sensor_lag from link_dynamics" in tied.reason
    apart = decide(loud, scores, distinctness=lambda a, b: 1.0, parameter_counts={"link_dynamics": 2, "sensor_lag": 1})
    assert apart.cause == "link_dynamics"
