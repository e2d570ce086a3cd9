"""PI gains from the model (cryod tune): the step's figures, the loop's margins, the search."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from scipy import signal

from cryod.cli import main
from cryod.control.pi import PiGains
from cryod.control.tuning import Tolerances, TuningError, loop_margins, step_performance, suggest_gains
from cryod.model import load_model
from cryod.model.dynamics import flange_transfer_functions
from tests.conftest import REPOSITORY

EXAMPLE = PiGains(10.0, 0.2)


def test_the_step_figures_are_those_of_the_control_study(reference_model):
    """docs/explanation/control.md (docs/figures/control_study.py, its own code): the example gains on the 50 ohm heater
    rise in 84 s, overshoot 0.5 mK, stay within 1 mK after 103 s, line 1.780 mK; the paper's gains on the
    17 ohm heater rise in 150 s (the heater's limit) with the heater at 0 W or its limit most of the time."""
    example = step_performance(reference_model, EXAMPLE, 5.0, 0.5)
    assert example.rise_s == pytest.approx(84.0, abs=1.0) and example.settle_s == pytest.approx(103.0, abs=1.5)
    assert example.overshoot_K * 1e3 == pytest.approx(0.5, abs=0.05) and example.line_K * 1e3 == pytest.approx(1.780,
                                                                                                                abs=0.003)
    paper = step_performance(reference_model, PiGains(80.0, 4.0), 5.0, 0.17)
    assert paper.rise_s == pytest.approx(150.0, abs=1.0)
    assert paper.at_bounds_fraction > 0.5 and paper.line_ratio > 1.05 and paper.offset_K < -0.5e-3


@pytest.mark.parametrize("gains", [EXAMPLE, PiGains(80.0, 4.0), PiGains(3.0, 27.0)])
def test_margins_agree_with_scipy_s_discretised_loop(reference_model, gains):
    """An independent route: the heater path discretised by scipy (zero-order hold), the PI as a z transfer
    function, the margins read off scipy's frequency response."""
    heater = flange_transfer_functions(reference_model)[0]
    period = 0.08
    numerator, denominator, _ = signal.cont2discrete((heater.numerator, heater.denominator), period, method="zoh")
    pi_numerator = [gains.proportional_w_per_K + gains.integral_w_per_K_s * period, -gains.proportional_w_per_K]
    loop = signal.dlti(np.polymul(pi_numerator, np.ravel(numerator)), np.polymul([1.0, -1.0], denominator), dt=period)
    omega = np.geomspace(1e-5, 0.9999 * np.pi / period, 200000)
    _, response = loop.freqresp(w=omega * period)
    magnitude = np.abs(response)
    crossing = np.flatnonzero(np.diff(np.sign(magnitude - 1.0)))[0]
    phase_margin = 180.0 + np.degrees(np.angle(response[crossing]))
    ours_phase, ours_gain = loop_margins(reference_model, gains, period, setting_delay_s=0.0)
    assert ours_phase == pytest.approx(phase_margin, abs=0.5)
    flips = np.flatnonzero((np.diff(np.sign(response.imag)) != 0) & (response.real[:-1] < 0.0))
    expected_gain = min(1.0 / magnitude[flips]) if flips.size else math.inf
    assert ours_gain == pytest.approx(expected_gain, rel=0.01)


def test_a_fast_integral_close_to_oscillating_is_seen_by_its_margin(reference_model):
    """Kp 3 W/K, Ki 27 W/(K s) settles on the model's step yet keeps 7 degrees of phase margin: refused."""
    phase, _ = loop_margins(reference_model, PiGains(3.0, 27.0))
    assert phase < 10.0
    step = step_performance(reference_model, PiGains(3.0, 27.0), 5.0, 0.17)
    assert any("phase margin" in problem for problem in Tolerances().violations(step))


@pytest.fixture(scope="module")
def coarse_suggestion(reference_model):
    return suggest_gains(reference_model, 5.0, 0.5, grid=(4, 3), refine_evaluations=4)


def test_the_suggestion_meets_the_tolerances_and_beats_the_example_gains(coarse_suggestion, reference_model):
    best = coarse_suggestion.best
    assert not coarse_suggestion.tolerances.violations(best)
    assert best.settle_s < step_performance(reference_model, EXAMPLE, 5.0, 0.5).settle_s
    assert all(math.isfinite(run.settle_s) or coarse_suggestion.tolerances.violations(run)
               for run in coarse_suggestion.runs)


def test_the_suggestion_holds_on_a_cryostat_that_is_not_the_model(coarse_suggestion, reference_model):
    """benchmarks/mismatch-model.yaml (heater path 0.7x, a 0.1 s sensor lag, a wandering cooler) and the heater
    path 1.3x: the gains found on the shipped model still settle, without ringing, with their margins."""
    mismatch = load_model(REPOSITORY / "benchmarks" / "mismatch-model.yaml")
    stronger = dataclasses.replace(reference_model, heater_to_flange=dataclasses.replace(
        reference_model.heater_to_flange, numerator=tuple(1.3 * c for c in reference_model.heater_to_flange.numerator)))
    nominal = coarse_suggestion.best
    for cryostat in (mismatch, stronger):
        step = step_performance(cryostat, nominal.gains, 5.0, 0.5)
        assert step.settle_s < 2.5 * nominal.settle_s and step.overshoot_K < 3e-3
        assert step.phase_margin_deg > 40.0 and abs(step.offset_K) < 1e-4


def test_a_step_the_heater_cannot_make_is_refused_with_the_reason(reference_model):
    with pytest.raises(TuningError, match="does not settle"):
        suggest_gains(reference_model, 8.0, 0.05, grid=(2, 2), refine_evaluations=0)


def test_the_command_refuses_a_number_that_is_not_plain(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["tune", "--setpoint", "1_5"])
    assert stop.value.code == 2 and "expected a number, got '1_5'" in capsys.readouterr().err


@pytest.mark.parametrize("arguments, message", [(["--setpoint", "5", "--from-power", "2"], "above R I_max^2"),
                                                (["--model", "/no/such/model.yaml"], "model.yaml")])
def test_the_command_refuses_bad_input(arguments, message, capsys):
    assert main(["tune", *arguments]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.slow
def test_the_command_prints_the_three_gains_as_json(capsys):
    assert main(["tune", "--setpoint", "5", "--duration", "500", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["suggested"]["settle_to_1mK_s"] < result["configured"]["settle_to_1mK_s"]
    assert result["configured_meets_tolerances"] and not result["paper_meets_tolerances"]
    assert result["suggested"]["phase_margin_deg"] >= 45.0
