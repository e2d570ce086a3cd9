import dataclasses

import pytest

from cryod.model import (
    HeaterNonlinearity, LinkDynamics, CoolerHarmonic, SensorLag, load_model, load_model_text, save_model,
)
from cryod.yaml_source import FileFormatError
from tests.conftest import CONFIG

GOOD = (CONFIG / "model.yaml").read_text()


def broken(old, new):
    assert old in GOOD, old
    return GOOD.replace(old, new, 1)


def line_of(text, fragment):
    return text.splitlines().index(next(l for l in text.splitlines() if fragment in l)) + 1


def test_shipped_model_loads(reference_model):
    assert reference_model.operating_point.flange_temperature_K == 4.23
    assert reference_model.ptc.angular_frequency_rad_s == 10.83
    assert reference_model.effect_names() == []
    assert reference_model.heater_to_ptc_stage.dc_gain == pytest.approx(2.77)


def test_unknown_key_names_file_line_and_key():
    text = broken("  flange_temperature_K: 4.23", "  flange_temperature_K: 4.23\n  flange_temprature_K: 4.3")
    with pytest.raises(FileFormatError) as caught:
        load_model_text(text, "lab.yaml")
    error = caught.value
    assert error.source == "lab.yaml"
    assert error.key == "operating_point.flange_temprature_K"
    assert error.line == line_of(text, "flange_temprature_K")
    assert "unknown key" in str(error) and str(error).startswith(f"lab.yaml:{error.line}:")


def test_improper_transfer_function():
    text = broken("    numerator: [5.333]", "    numerator: [1.0, 2.0, 5.333]")
    with pytest.raises(FileFormatError, match="improper") as caught:
        load_model_text(text, "lab.yaml")
    assert caught.value.key == "transfer_functions.ptc_to_flange.denominator"
    assert caught.value.line == line_of(text, "denominator: [0.1996")


def test_negative_time_constant():
    text = broken("denominator: [26.48, 1.0]", "denominator: [-26.48, 1.0]")
    with pytest.raises(FileFormatError, match="time constant must be positive") as caught:
        load_model_text(text, "lab.yaml")
    assert caught.value.key == "transfer_functions.flange_to_thermometer.denominator"
    assert caught.value.line == line_of(text, "[-26.48")


def test_missing_field():
    text = broken("  heat_capacity_J_per_K: 0.1655\n", "")
    with pytest.raises(FileFormatError, match="missing required key") as caught:
        load_model_text(text, "lab.yaml")
    assert caught.value.key == "ptc.heat_capacity_J_per_K"
    assert caught.value.line == line_of(text, "ptc:")


def test_missing_section_and_wrong_type():
    with pytest.raises(FileFormatError, match="transfer_functions.*missing"):
        load_model_text("format: cryod-model v1\noperating_point: {flange_temperature_K: 4, ptc_stage_temperature_K: 3}\n")
    with pytest.raises(FileFormatError, match="must be a number") as caught:
        load_model_text(broken("angular_frequency_rad_s: 10.83", "angular_frequency_rad_s: fast"), "lab.yaml")
    assert caught.value.key == "ptc.angular_frequency_rad_s"


def test_wrong_units_and_duplicate_key():
    with pytest.raises(FileFormatError, match="in K/K, not 'mK/K'"):
        load_model_text(broken("    units: K/K", "    units: mK/K"))
    with pytest.raises(FileFormatError, match="given twice"):
        load_model_text(broken("  phase_rad: 3.02", "  phase_rad: 3.02\n  phase_rad: 1.0"))


def test_invalid_yaml_and_missing_file(tmp_path):
    with pytest.raises(FileFormatError, match="not valid YAML") as caught:
        load_model_text("format: [unclosed\n", "lab.yaml")
    assert caught.value.line is not None
    with pytest.raises(FileFormatError, match="file not found"):
        load_model(tmp_path / "nope.yaml")


def test_effects_parse_and_validate():
    text = broken("effects: {}", """effects:
  sensor_lag: {flange_thermometer_time_constant_s: 0.3}
  dead_time: {heater_to_flange_s: 1.5}
  link_dynamics: {time_constant_s: 0.05, gain_factor: 1.2}
  heat_capacity_temperature: {exponent: 1.5, reference_temperature_K: 4.23}
  heater_nonlinearity: {quadratic_coefficient_per_W: 0.4}
  ptc_frequency_drift: {rate_rad_s_per_hour: 0.02}""")
    model = load_model_text(text)
    assert set(model.effect_names()) == {"sensor_lag", "dead_time", "link_dynamics", "heat_capacity_temperature",
                                         "heater_nonlinearity", "ptc_frequency_drift"}
    assert model.effects.sensor_lag == SensorLag(0.3, 0.0)
    with pytest.raises(FileFormatError, match="greater than 0") as caught:
        load_model_text(broken("effects: {}", "effects:\n  sensor_lag: {flange_thermometer_time_constant_s: 0}"))
    assert caught.value.key == "effects.sensor_lag.flange_thermometer_time_constant_s"
    with pytest.raises(FileFormatError, match="unknown key"):
        load_model_text(broken("effects: {}", "effects:\n  thermal_runaway: {rate: 1}"))


def test_save_and_load_round_trip(tmp_path, reference_model):
    extended = reference_model.with_effects(
        sensor_lag=SensorLag(0.25, 0.01), link_dynamics=LinkDynamics(0.05, 1.1),
        heater_nonlinearity=HeaterNonlinearity(0.3),
    ).with_ptc(harmonics=(CoolerHarmonic(2, 0.01, 0.5), CoolerHarmonic(3, 0.004, -1.0)))
    path = save_model(extended, tmp_path / "extended.yaml", header="fitted by a test")
    assert path.read_text().startswith("# fitted by a test\n")
    again = load_model(path)
    assert dataclasses.replace(again, source="") == dataclasses.replace(extended, source="")
    assert again.effect_names() == ["sensor_lag", "link_dynamics", "heater_nonlinearity", "ptc_harmonics"]
