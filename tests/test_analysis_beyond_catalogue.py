"""The analysis beyond its catalogue: the new cooler causes in the model, base_model_off, what is left, equivalences."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from cryod.analysis.equivalence import equivalents
from cryod.analysis.residual_signature import classify_peak, spectral_peaks
from cryod.model import (
    CryostatPlant, FileFormatError, HeaterPathCorrection, PtcAmplitudeModulation, PtcStageDrift, load_model, load_model_text, model_to_dict,
    save_model, simulate,
)
from tests.hidden_effects import analysed, base_model, other_day

MODULATION = PtcAmplitudeModulation(0.15, 600.0, 0.4)
DRIFT = PtcStageDrift(1.5e-3, 600.0, 0.6, 150.0, 4)
CORRECTION = HeaterPathCorrection((3.0, 30.0), (0.2, -0.1), (0.0, 0.05))


def test_new_effects_round_trip_through_the_model_file(tmp_path):
    model = load_model().with_effects(ptc_amplitude_modulation=MODULATION, ptc_stage_drift=DRIFT,
                                      heater_path_correction=CORRECTION)
    save_model(model, tmp_path / "m.yaml")
    assert load_model(tmp_path / "m.yaml").effects == model.effects


def test_a_correction_with_a_gain_short_is_refused():
    data = model_to_dict(load_model())
    data["effects"] = {"heater_path_correction": {"time_constants_s": [3, 30], "flange_gains_K_per_W": [0.1],
                                                  "ptc_stage_gains_K_per_W": [0, 0]}}
    with pytest.raises(FileFormatError, match="one gain per time constant"):
        load_model_text(yaml.safe_dump(data))


def test_the_envelope_scales_both_lines_and_the_drift_reaches_the_flange():
    model = load_model()
    t = np.arange(0.0, 1200.0, 0.08)
    heater = np.zeros(t.size)
    plain = simulate(model, t, heater)
    modulated = simulate(model.with_effects(ptc_amplitude_modulation=MODULATION), t, heater)
    envelope = MODULATION.envelope(t)
    point = model.operating_point
    assert np.allclose(modulated.ptc_stage_K - point.ptc_stage_temperature_K,
                       envelope * (plain.ptc_stage_K - point.ptc_stage_temperature_K), atol=1e-12)
    drifting = simulate(model.with_effects(ptc_stage_drift=DRIFT), t, heater)
    flange, stage = DRIFT.offsets_K(t)
    assert np.allclose(drifting.ptc_stage_K - plain.ptc_stage_K, stage, atol=1e-12)
    assert np.allclose(drifting.flange_K - plain.flange_K, flange, atol=1e-12)
    assert 0.3e-3 < np.std(stage) < 3e-3 and 0.3 < np.std(flange) / np.std(stage) < 0.7


def test_the_stepping_plant_agrees_with_the_whole_record_simulation():
    model = load_model().with_effects(ptc_amplitude_modulation=MODULATION, ptc_stage_drift=DRIFT,
                                      heater_path_correction=CORRECTION)
    t = np.arange(0.0, 300.0, 0.08)
    heater = np.where(t > 50.0, 0.01, 0.0)
    whole = simulate(model, t, heater, initial_heater_power_w=0.0)
    plant = CryostatPlant(model)
    stepped = []
    for instant, power in zip(t, heater):
        plant.advance_to(instant)
        stepped.append(plant.temperatures())
        plant.set_heater_power(power, instant)
    stepped = np.array(stepped)
    assert np.allclose(stepped[:, 0], whole.flange_K, atol=1e-9)
    assert np.allclose(stepped[:, 1], whole.ptc_stage_K, atol=1e-9)


def test_peaks_are_placed_against_the_harmonics_and_their_sidebands():
    assert classify_peak(2 * 1.72, 1.72, 12.5, 1e-3) == "harmonic 2"
    assert "sideband of harmonic 1" in classify_peak(1.72 - 0.005, 1.72, 12.5, 1e-3)
    assert classify_peak(0.37, 1.72, 12.5, 1e-3) == "not at the cooler's harmonics"
    generator = np.random.default_rng(1)
    t = np.arange(0.0, 1800.0, 0.08)
    residual = generator.normal(0.0, 20e-6, t.size) + 5e-6 * np.sin(2 * np.pi * 0.37 * t)
    peaks = spectral_peaks(residual, "T2", 12.5, 1.72)
    assert len(peaks) == 1 and abs(peaks[0].frequency_hz - 0.37) < 2e-3
    assert abs(peaks[0].amplitude_K - 5e-6) < 1e-6 and peaks[0].significance >= 5
    assert spectral_peaks(generator.normal(0.0, 20e-6, t.size), "T2", 12.5, 1.72) == []


def test_both_thermometers_lagging_alike_read_as_a_heater_lag():
    named = SimpleNamespace(cause="sensor_lag", fit=SimpleNamespace(parameters={
        "flange_thermometer_time_constant_s": 0.4, "ptc_stage_thermometer_time_constant_s": 0.41}))
    analysis = SimpleNamespace(causes=[named], decision=SimpleNamespace(tied=()))
    readings = equivalents(analysis, named)
    assert [reading["reading"].split(":")[0] for reading in readings] == ["heater lag"]
    named.fit.parameters["ptc_stage_thermometer_time_constant_s"] = 0.0
    assert equivalents(analysis, named) == []


@pytest.mark.slow
def test_a_heater_15_percent_stronger_is_base_model_off_not_a_nonlinearity():
    model = other_day(base_model(), 1)
    model = dataclasses.replace(model, heater_to_flange=model.heater_to_flange * 1.15,
                                heater_to_ptc_stage=model.heater_to_ptc_stage * 1.15)
    analysis = analysed(model, "identification", 1800.0, 3)
    assert analysis.cause == "base_model_off", analysis.decision.reason
    asked = {row.parameter: row.fitted / row.shipped for row in analysis.beyond_recalibration.parameters}
    assert abs(asked["heater_to_flange static gain"] - 1.15) < 0.03
    assert "cryod identify" in analysis.decision.reason and not analysis.causes


@pytest.mark.slow
def test_a_breathing_stroke_is_named_with_its_depth_and_period():
    model = other_day(base_model(), 1).with_effects(ptc_amplitude_modulation=MODULATION)
    analysis = analysed(model, "pi_only", 1800.0, 3)
    assert analysis.cause == "ptc_amplitude_modulation", analysis.decision.reason
    parameters = analysis.causes[0].fit.parameters
    assert abs(parameters["depth"] - 0.15) < 0.01 and abs(parameters["period_s"] - 600.0) < 20.0


@pytest.mark.slow
def test_an_effect_outside_the_catalogue_is_described_and_extended():
    model = other_day(base_model(), 0)
    model = dataclasses.replace(model, heater_to_flange=model.heater_to_flange
                                + load_model().heater_to_flange.first_order_lag(20.0, 0.4))
    analysis = analysed(model, "identification", 1800.0, 2)
    assert analysis.cause == "unexplained", analysis.decision.reason
    assert analysis.generic is not None and analysis.generic.score.gain.ratio > 1.0
    assert analysis.residual_signature.sentences()
