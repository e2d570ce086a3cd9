"""``cryod identify`` recovers the shipped model from records simulated with it."""

import json

import numpy as np
import pytest

from cryod import cli
from cryod.analysis.record_data import RecordData
from cryod.identification.fit import IdentificationError, identify
from cryod.model import load_model
from cryod.records.record import Record, write_record
from simulated_hw.measurement_programs import make_record

from tests.conftest import CONFIG


def _records(model):
    made = []
    for protocol, duration, seed in (("identification", 1200.0, 11), ("pi_only", 900.0, 12)):
        record = make_record(model, protocol, duration_s=duration, seed=seed)
        made.append(record)
    return made


@pytest.fixture(scope="module")
def shipped_records(reference_model):
    return _records(reference_model.with_ptc(phase_rad=-0.4))


def test_identify_recovers_the_shipped_model_from_the_printed_one(shipped_records, reference_model, printed_model):
    data = [RecordData.from_record(Record(r.metadata, r.columns, source="sim")) for r in shipped_records]
    result = identify(data, printed_model)
    model = result.model
    assert result.flange_time_constants_s == pytest.approx((26.48, 165.41), rel=0.01)
    assert model.heater_to_thermometer.dc_gain == pytest.approx(reference_model.heater_to_thermometer.dc_gain,
                                                                rel=0.002)
    assert model.heater_to_flange.numerator == pytest.approx(reference_model.heater_to_flange.numerator, rel=0.01)
    assert result.stage_gain_K_per_W == pytest.approx(2.77, rel=0.01)
    assert result.stage_time_constant_s == pytest.approx(135.0, rel=0.01)
    for path in ("heater_to_thermometer", "ptc_heat_to_thermometer"):
        assert getattr(model, path).frequency_response(10.83) == pytest.approx(
            getattr(reference_model, path).frequency_response(10.83), rel=0.01)
    assert model.ptc_to_flange.denominator == pytest.approx(reference_model.ptc_to_flange.denominator, rel=0.02)
    assert model.operating_point.flange_temperature_K == pytest.approx(4.23, abs=2e-5)
    assert model.operating_point.ptc_stage_temperature_K == pytest.approx(3.34, abs=1e-4)
    assert model.ptc.angular_frequency_rad_s == pytest.approx(10.83, abs=1e-5)
    assert model.ptc.ptc_stage_amplitude_K == pytest.approx(0.12361, rel=1e-3)
    assert model.ptc.phase_rad == pytest.approx(-0.4, abs=1e-3)
    assert model.ptc.harmonics == ()
    assert result.noise_rms_K == pytest.approx((20e-6, 0.3e-3), rel=0.05)
    assert all(max(pair) < 1.05 for pair in result.residual_rms_in_noise)


def test_identify_command_writes_a_loadable_model(shipped_records, tmp_path, capsys):
    paths = []
    for index, record in enumerate(shipped_records):
        paths.append(tmp_path / f"record-{index}.csv")
        write_record(paths[-1], record.columns, record.metadata)
    out = tmp_path / "identified.yaml"
    status = cli.main(["identify", *map(str, paths), "--base", str(CONFIG / "model-paper-printed.yaml"),
                       "--out", str(out), "--json"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    summary = json.loads(captured.out)
    assert summary["heater_to_thermometer_time_constants_s"] == pytest.approx([26.48, 165.41], rel=0.01)
    assert summary["ptc_line_T2_lag_behind_T5_rad"] == pytest.approx(1.134, abs=0.01)
    model = load_model(out)
    assert model.heater_to_ptc_stage.dc_gain == pytest.approx(2.77, rel=0.01)
    # refuses to overwrite, names what to do
    assert cli.main(["identify", str(paths[0]), "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err


def test_identify_needs_the_heater_to_move(reference_model, tmp_path, capsys):
    t = np.arange(0.0, 600.0, 0.08)
    flange = 4.23 + 1.7e-3 * np.sin(10.83 * t)
    stage = 3.34 + 0.12 * np.sin(10.83 * t + 1.1)
    data = RecordData.from_record(Record({}, {"time_s": t, "T2_K": flange, "T5_K": stage, "heater_W": 0 * t,
                                              "setpoint_K": np.nan * t}, source="flat"))
    with pytest.raises(IdentificationError, match="heater never changes"):
        identify([data], reference_model)
    path = tmp_path / "flat.csv"
    write_record(path, {"time_s": t, "T2_K": flange, "T5_K": stage, "heater_W": 0 * t, "setpoint_K": np.nan * t})
    assert cli.main(["identify", str(path), "--out", str(tmp_path / "m.yaml")]) == 1
    assert "heater never changes" in capsys.readouterr().err
    assert not (tmp_path / "m.yaml").exists()


def test_the_line_panel_shows_a_settled_stretch_of_a_closed_loop_record_or_of_a_step_record():
    from cryod.identification.figures import settled_window

    t = np.arange(0.0, 1800.0, 0.08)
    line = 1.7e-3 * np.sin(10.83 * t)
    # regulating from the start: the heater changes at every tick, T2 climbs 0.77 K to the setpoint
    regulated = 5.0 - 0.77 * np.exp(-t / 165.0) + line
    window = settled_window(t, regulated, 7, 3.5)
    slow = 5.0 - 0.77 * np.exp(-t[window] / 165.0)
    assert t[window][0] > 1500.0 and np.ptp(slow) < 1e-6          # T2's drift there under a microkelvin
    # heater steps every 600 s: late in a hold, where T2 has settled after its step
    steps = 4.23 + 0.06 * np.where(t >= 600.0, 1.0 - np.exp(-(t - 600.0) / 100.0), 0.0) \
        - 0.06 * np.where(t >= 1200.0, 1.0 - np.exp(-(t - 1200.0) / 100.0), 0.0) + line
    window = settled_window(t, steps, 7, 3.5)
    start = t[window][0]
    assert 500.0 < start < 600.0 or 1100.0 < start < 1200.0 or start > 1700.0
