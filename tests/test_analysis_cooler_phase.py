"""A wandering cooler: its phase followed sample by sample in T5, the line replayed with it.

The phase is the feedforward's tracker's (one tracker, not two), made zero-lag;
the drift's parameters are the model's form fitted to it; a cooler wandering by
+-0.8 % over 15 minutes is named ``ptc_frequency_drift`` with them.
"""

import math

import numpy as np
import pytest

from cryod.cooler.line import estimate_ptc_line, fit_drift_to_phase, measured_cycle
from cryod.cooler.phase import CoolerPhaseTracker
from cryod.model import CoolerFrequencyDrift, load_model, save_model
from cryod.model.cooler_cycle import MeasuredCoolerCycle

from tests.hidden_effects import analysed, base_model, named_parameters, other_day, within
from simulated_hw.hidden_effects import perturbed_base

OMEGA = 10.83
WANDERS = [CoolerFrequencyDrift(0.0, 0.01 * OMEGA, 600.0, 0.7), CoolerFrequencyDrift(0.02, 0.008 * OMEGA, 1800.0, -2.0),
           CoolerFrequencyDrift(-0.03)]


def _stage(drift, seed=1, duration_s=3600.0):
    generator = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 0.08) + generator.uniform(0.0, 0.02, int(round(duration_s / 0.08)))
    t -= t[0]
    phase = OMEGA * t + drift.phase_offset(t)
    stage = (3.34 + 0.12 * np.sin(phase + 1.0) + 0.01 * np.sin(2.0 * phase + 0.4)
             + generator.normal(0.0, 3e-4, t.size))
    return t, phase, stage


@pytest.mark.parametrize("drift", WANDERS)
def test_measured_phase_follows_a_wandering_cooler_without_lag(drift):
    t, phase, stage = _stage(drift)
    cycle = measured_cycle(t, stage, OMEGA)
    error = (cycle.phase_rad(t) - phase)[t > 10.0]
    error -= error.mean()                  # a constant phase is the line's own (fitted with its amplitude)
    assert np.std(error) < 5e-4 and np.ptp(error) < 3e-3
    # T5 replayed at the measured phase: what is left is the noise (within 1 % of its variance)
    line = estimate_ptc_line(t, stage, np.ones((t.size, 1)), orders=(1, 2), cycle=cycle)
    fitted = sum(c.amplitude_K * np.sin(c.order * cycle.phase_rad(t) + c.phase_rad) for c in line.components)
    residual = stage - fitted
    residual -= residual.mean()
    assert np.var(residual[t > 10.0]) < 1.01 * (3e-4) ** 2


def test_the_phase_is_followed_by_the_feedforwards_tracker(monkeypatch):
    """One tracker for the feedforward and the analysis: measured_cycle runs CoolerPhaseTracker on every reading."""
    calls = []
    update = CoolerPhaseTracker.update

    def counted(self, time_s, value):
        calls.append(time_s)
        return update(self, time_s, value)

    monkeypatch.setattr(CoolerPhaseTracker, "update", counted)
    t, _, stage = _stage(WANDERS[0], duration_s=300.0)
    measured_cycle(t, stage, OMEGA)
    assert calls == t.tolist()


@pytest.mark.parametrize("drift", WANDERS)
def test_drift_form_fitted_to_the_measured_phase(drift):
    t, _, stage = _stage(drift, seed=2)
    omega, fitted = fit_drift_to_phase(measured_cycle(t, stage, OMEGA))
    # the form's omega_0 and the start's frequency differ by the wander's value at 0
    assert omega + fitted.angular_frequency_offset(0.0) == pytest.approx(
        OMEGA + drift.angular_frequency_offset(0.0), abs=1e-3)
    assert fitted.rate_rad_s_per_hour == pytest.approx(drift.rate_rad_s_per_hour, abs=2e-3)
    assert fitted.wander_amplitude_rad_s == pytest.approx(drift.wander_amplitude_rad_s, rel=0.02, abs=1e-4)
    if drift.wander_amplitude_rad_s:
        assert fitted.wander_period_s == pytest.approx(drift.wander_period_s, rel=0.02)
        assert math.remainder(fitted.wander_phase_rad - drift.wander_phase_rad, 2 * math.pi) == pytest.approx(
            0.0, abs=0.05)


def test_measured_cycle_interpolates_and_continues_at_its_ends():
    cycle = MeasuredCoolerCycle([0.0, 1.0, 2.0], [0.0, 10.0, 20.5], [10.0, 10.25, 10.5])
    assert cycle.phase_rad(1.5) == pytest.approx(15.25)
    assert cycle.phase_rad(-1.0) == pytest.approx(-10.0) and cycle.phase_rad(3.0) == pytest.approx(31.0)
    with pytest.raises(ValueError, match="increase"):
        MeasuredCoolerCycle([0.0, 0.0], [0.0, 1.0], [1.0, 1.0])


def test_wander_phase_is_part_of_the_drift_form_and_its_file(tmp_path, reference_model):
    drift = CoolerFrequencyDrift(0.01, 0.05, 900.0, 1.2)
    t = np.linspace(0.0, 1800.0, 7)
    phase = drift.phase_offset(t)
    assert phase[0] == 0.0
    # the phase offset is the integral of the frequency offset
    fine = np.linspace(0.0, 1800.0, 200001)
    integral = np.concatenate(([0.0], np.cumsum(0.5 * (drift.angular_frequency_offset(fine[1:])
                                                          + drift.angular_frequency_offset(fine[:-1]))
                                                 * np.diff(fine))))
    assert phase == pytest.approx(np.interp(t, fine, integral), abs=1e-6)
    path = save_model(reference_model.with_effects(ptc_frequency_drift=drift), tmp_path / "wander.yaml")
    assert load_model(path).effects.ptc_frequency_drift == drift


@pytest.mark.parametrize("protocol, duration_s, wander_phase_rad, perturbation", [
    ("pi_only", 1800.0, 0.0, None),          # the exact shipped model, the cooler's frequency +-0.8 % over 900 s
    ("identification", 1200.0, 2.0, 4),      # another phase of the wander, base parameters off
])
def test_wandering_cooler_is_named_with_its_parameters(protocol, duration_s, wander_phase_rad, perturbation):
    drift = CoolerFrequencyDrift(0.0, 0.008 * OMEGA, 900.0, wander_phase_rad)
    model = other_day(base_model(), 1).with_effects(ptc_frequency_drift=drift)
    if perturbation is not None:
        model, _ = perturbed_base(model, perturbation)
    analysis = analysed(model, protocol, duration_s, 3)
    assert analysis.cause_names == ["ptc_frequency_drift"], analysis.decision.reason
    fitted = named_parameters(analysis, "ptc_frequency_drift")
    assert within(fitted["wander_amplitude_rad_s"], drift.wander_amplitude_rad_s)
    assert within(fitted["wander_period_s"], drift.wander_period_s)
    assert analysis.decision.gain.extended < 1.05
