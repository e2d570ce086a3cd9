"""Commissioning across the range: identification about a setpoint, the zone table written and read
back, the feedforward's limit at each setpoint."""

import dataclasses
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from cryod.analysis.record_data import RecordData
from cryod.config import load_config
from cryod.control.pi import PiGains
from cryod.control.zone_commissioning import (
    limits_across_range, model_at_temperature, model_of_zone, zone_table_text, zone_uppers,
)
from cryod.control.zones import Zone, ZoneTable
from cryod.identification.experiment import ExperimentPlan, ExperimentRunner
from cryod.identification.setpoint_series import part_about_setpoint, plans_at, records_about_setpoint
from cryod.records.compression import record_path_now
from cryod.model import TEMPERATURE_MODEL_PATH, linearised_at, load_model, save_model, steady_state
from tests.conftest import CONFIG
from tests.example_config import PI_SECTION, with_zone_table


def test_zone_boundaries_lie_half_way_and_the_last_covers_the_setpoints_allowed():
    assert zone_uppers([5.0, 8.0, 12.0, 16.0, 20.0, 24.0], 25.0) == [6.5, 10.0, 14.0, 18.0, 22.0, 25.0]
    assert zone_uppers([5.0], 4.0) == [5.0]
    with pytest.raises(ValueError, match="increasing order"):
        zone_uppers([8.0, 5.0], 25.0)


def test_a_written_table_is_read_back_pasted_or_included(tmp_path):
    model = load_model(CONFIG / "model.yaml")
    table = ZoneTable((Zone(6.5, PiGains(12.6, 4.13), model, "zone-model.yaml"),
                       Zone(20.0, PiGains(300.0, 0.5), max_heater_power_W=0.4)))
    text = zone_table_text(table, header="commissioned\non the simulated cryostat")
    assert text.startswith("# commissioned\n# on the simulated cryostat\nzones:\n")
    (tmp_path / "zones.yaml").write_text(text)
    path, _ = with_zone_table(tmp_path, "  zones: zones.yaml\n")
    included = load_config(path).control.zones
    pasted_text = "".join(f"  {line}\n" for line in text.splitlines())
    pasted, _ = with_zone_table(tmp_path, pasted_text)
    for read in (included, load_config(pasted).control.zones):
        assert [zone.upper_K for zone in read.zones] == [6.5, 20.0]
        assert read.zones[0].gains == PiGains(12.6, 4.13) and read.zones[1].max_heater_power_W == 0.4
        assert read.zones[0].feedforward_model.heater_to_thermometer == model.heater_to_thermometer
        assert read.zones[1].feedforward_model is None
    assert PI_SECTION in (CONFIG / "cryod.yaml").read_text()


def test_the_limit_across_the_range_uses_the_model_that_holds_at_each_setpoint():
    cryostat = load_model(TEMPERATURE_MODEL_PATH)
    rows = limits_across_range([5.0, 12.0, 24.0], model_at_temperature(cryostat), 1000.0, 0.1)
    assert [row.problem for row in rows] == ["", "", ""]
    opens = [row.open_line_K for row in rows]
    assert opens[0] > 5 * opens[1] > 25 * opens[2] > 0.0
    assert all(row.ptc_periodic_limit_K <= row.open_line_K for row in rows)
    assert rows[0].limited_by == "authority" and rows[2].limited_by == "noise"     # 0.12 W of 10 W at 5 K
    assert rows[2].mean_heater_power_W == pytest.approx(5.5614, abs=1e-3)
    shipped = load_model(CONFIG / "model.yaml")
    table = ZoneTable((Zone(6.5, PiGains(1.0, 0.1), linearised_at(cryostat, 5.0), "5 K"),
                       Zone(25.0, PiGains(1.0, 0.1))))
    at = model_of_zone(table, shipped)
    assert at(5.0).description.startswith("linearised at T2 = 5 K") and at(12.0) is shipped
    far = limits_across_range([30.0], model_at_temperature(cryostat), 50.0, 0.1)[0]
    assert far.problem and math.isnan(far.ptc_periodic_limit_K)          # out of the 0.5 W heater's reach


def test_about_a_setpoint_the_experiment_regulates_holds_and_steps_the_setpoint():
    plan = ExperimentPlan(setpoint_K=12.0, setpoint_step_K=0.05, settle_window_s=20.0, min_settle_s=0.0,
                          max_settle_s=200.0, line_hold_s=30.0)
    plan.check(10.0)
    commands, notes, stops = [], [], []
    runner = ExperimentRunner(plan, lambda name, value: commands.append((name, value)), stops.append, notes.append,
                              expected_settle_s=50.0)
    heater = lambda t: 1.8 + 0.2 * math.exp(-t / 10.0)                    # noqa: E731  settles, as under PI
    t = 0.0
    while not stops and t < 2000.0:
        ramp = min(11.0 + t / 60.0, 12.0) if len(commands) == 1 else 12.05     # 1 K/min, from 11 K
        runner(SimpleNamespace(state="closed", time_s=t, T2_K=ramp, setpoint_K=ramp,
                               heater_W=heater(t if t < 500 else t - 500)))
        t += 0.5
    assert commands == [("setpoint", 12.0), ("setpoint", 12.05)]
    assert runner.outcome == "finished" and [phase for phase, _, _ in runner.phase_log] == ["regulate", "line", "step"]
    assert runner.phase_log[0][1] == 60.0                                 # counted from the ramp's end
    assert notes[1] == "the setpoint reached 12 K: the regulation settles from here"
    assert notes[2].startswith("phase regulate settled after") and "the heater moved" in notes[2]
    with pytest.raises(ValueError, match="closed loop"):
        ExperimentPlan(setpoint_K=12.0, base_power_w=0.1).check(10.0)
    with pytest.raises(ValueError, match="increasing order"):
        plans_at([12.0, 8.0], ExperimentPlan())


def test_an_experiment_across_midnight_is_fitted_from_the_record_with_the_step_on():
    """The approach's day file (a ramp: its setpoint changes every tick) stays out; the step's file is cut to the
    hold and the step, the file after it is taken whole."""
    def record(time_s, setpoint):
        return RecordData(time_s, np.asarray(setpoint, float), np.full(time_s.size, 8.0), np.full(time_s.size, 1.8),
                          np.asarray(setpoint, float))

    time_s = np.arange(0.0, 1000.0, 1.0)
    ramp = record(time_s, 11.0 + time_s / 1000.0)
    step = record(time_s, np.where(time_s < 600.0, 12.0, 12.05))
    after = record(time_s, np.full(time_s.size, 12.05))
    parts = records_about_setpoint([ramp, step, after], line_hold_s=120.0)
    assert len(parts) == 2 and parts[0].time_s[0] == 480.0 and parts[1] is after
    assert records_about_setpoint([step], 120.0)[0].time_s[0] == 480.0


def test_a_record_compressed_at_the_days_end_is_found_where_it_is_now(tmp_path):
    written = tmp_path / "cryod-2026-11-28.csv"
    assert record_path_now(written) == written                       # neither: as written
    written.write_text("x")
    assert record_path_now(written) == written
    compressed = tmp_path / "cryod-2026-11-28.csv.gz"
    compressed.write_bytes(b"")
    written.unlink()
    assert record_path_now(written) == compressed


def test_a_fit_whose_heater_cools_the_flange_or_that_misses_its_record_is_refused(monkeypatch):
    import cryod.identification.setpoint_series as series
    from cryod.identification.fit import IdentificationError
    from cryod.model.transfer_function import TransferFunction

    shipped = load_model(CONFIG / "model.yaml")
    cooling = dataclasses.replace(shipped, heater_to_flange=TransferFunction((-0.03,), (52.0, 1.0)))
    fitted = {"model": cooling, "residual_rms_in_noise": [(1.01, 1.0)]}
    monkeypatch.setattr(series, "identify_model", lambda records, base, **options: SimpleNamespace(**fitted))
    time_s = np.arange(0.0, 100.0, 1.0)
    data = RecordData(time_s, np.full(100, 24.0), np.full(100, 18.0), np.full(100, 5.5), np.full(100, 24.0))
    with pytest.raises(IdentificationError, match="static gain is -0.03 K/W: more heater would cool the flange"):
        series.identify_at_setpoint(24.0, [data], ["r.csv"], shipped, 120.0)
    # a positive gain that leaves 77 times the noise: not a description of the record
    fitted.update(model=dataclasses.replace(shipped, heater_to_flange=TransferFunction((0.015,), (91.0, 1.0))),
                  residual_rms_in_noise=[(77.2, 1.04)])
    with pytest.raises(IdentificationError, match="leaves 77 times T2's noise on T2"):
        series.identify_at_setpoint(24.0, [data], ["r.csv"], shipped, 120.0)


def test_the_fit_takes_the_hold_and_the_step_about_the_setpoint():
    time_s = np.arange(0.0, 1000.0, 1.0)
    setpoint = np.where(time_s < 600.0, 12.0, 12.05)
    data = RecordData(time_s, np.full(time_s.size, 12.0), np.full(time_s.size, 8.0), np.full(time_s.size, 1.8),
                      setpoint)
    part = part_about_setpoint(data, line_hold_s=120.0)
    assert part.time_s[0] == 480.0 and part.time_s[-1] == 999.0
    held = RecordData(time_s, data.flange_K, data.ptc_stage_K, data.heater_w, np.full(time_s.size, 12.0))
    assert part_about_setpoint(held, 120.0) is held


def test_the_example_for_25_K_has_a_heater_and_limits_fit_for_it():
    config = load_config(CONFIG / "cryod-4-25K.yaml")
    cryostat = load_model(config.simulation.model)
    assert cryostat.temperature_dependence is not None
    power_w, stage_K = steady_state(cryostat, config.control.setpoint_max_K)
    assert config.heater.resistance_ohm == 1000.0 and config.heater.max_current_A == 0.1
    assert power_w < 0.7 * config.heater.max_power_w                     # headroom for ramps and the feedforward
    assert stage_K < config.safety.ptc_stage_max_K - 3.0
    assert config.control.setpoint_max_K < config.safety.flange_max_K


# -- the commands ---------------------------------------------------------------------------
def test_feedforward_limit_across_a_range_prints_each_setpoint_with_its_model(capsys):
    from cryod.cli import main

    arguments = ["feedforward-limit", "--config", str(CONFIG / "cryod-4-25K.yaml"), "--model",
                 str(TEMPERATURE_MODEL_PATH), "--setpoints", "5,24", "--json"]
    assert main(arguments) == 0
    result = json.loads(capsys.readouterr().out)
    assert [row["setpoint_K"] for row in result["setpoints"]] == [5.0, 24.0]
    assert result["setpoints"][0]["limited_by"] == "authority" and result["setpoints"][1]["limited_by"] == "noise"
    assert result["setpoints"][1]["mean_heater_power_W"] == pytest.approx(5.5614, abs=1e-3)
    assert main(arguments[:-3] + ["--zones", str(CONFIG / "cryod.yaml")]) == 2
    assert "give the range with --setpoints" in capsys.readouterr().err


@pytest.mark.parametrize("arguments, message", [
    (["--zones", "5:model.yaml"], "SETPOINT_K=MODEL_FILE"),
    (["--zones", f"5={TEMPERATURE_MODEL_PATH}"], "not a zone's model"),
    (["--zones", f"5={CONFIG / 'model.yaml'}", "--zones-out", str(CONFIG / "model.yaml")], "never writes over its input"),
])
def test_tune_zones_refuses_what_it_cannot_use(arguments, message, capsys):
    from cryod.cli import main

    try:
        code = main(["tune", "--config", str(CONFIG / "cryod-4-25K.yaml"), *arguments])
    except SystemExit as stop:
        code = stop.code
    assert code == 2 and message in capsys.readouterr().err


@pytest.mark.slow
def test_tune_zones_writes_a_table_the_configuration_reads(tmp_path, capsys):
    from cryod.cli import main

    cryostat = load_model(TEMPERATURE_MODEL_PATH)
    for setpoint in (5.0, 6.0):
        save_model(linearised_at(cryostat, setpoint), tmp_path / f"model-{setpoint:g}K.yaml")
    out = tmp_path / "zones.yaml"
    assert main(["tune", "--config", str(CONFIG / "cryod-4-25K.yaml"), "--zones", f"5={tmp_path / 'model-5K.yaml'}",
                 f"6={tmp_path / 'model-6K.yaml'}", "--zones-out", str(out), "--duration", "1200", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [zone["upper_K"] for zone in result["zones"]] == [5.5, 25.0]
    assert all(zone["overshoot_mK"] <= 1.0 for zone in result["zones"])
    path, _ = with_zone_table(tmp_path, "  zones: zones.yaml\n", ("  setpoint_max_K: 20.0", "  setpoint_max_K: 25.0"),
                         ("  flange_max_K: 25.0", "  flange_max_K: 28.0"))
    table = load_config(path).control.zones
    assert table.zones[0].feedforward_model.heater_to_thermometer.dc_gain == pytest.approx(
        linearised_at(cryostat, 5.0).heater_to_thermometer.dc_gain)


@pytest.mark.slow
def test_identify_about_a_setpoint_finds_the_cryostat_there(tmp_path, capsys):
    """On the temperature-dependent simulated cryostat, about 12 K: the model fitted to the hold and the step has
    the linear model's gain at the line and its line within 10 %, its static gain within 15 %."""
    from cryod.cli import main

    assert main(["identify", "--acquire", "--simulate", "--config", str(CONFIG / "cryod-4-25K.yaml"), "--setpoints",
                 "12", "--out", str(tmp_path / "models"), "--data-dir", str(tmp_path / "data"), "--socket",
                 str(tmp_path / "control.sock"), "--bootstrap", "0", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    fitted = load_model(result["setpoints"][0]["model"])
    truth = linearised_at(load_model(TEMPERATURE_MODEL_PATH), 12.0)
    omega = truth.ptc.angular_frequency_rad_s

    def line(model):
        return abs(model.ptc_heat_to_thermometer.frequency_response(omega)) * model.ptc.heat_capacity_J_per_K \
            * omega * model.ptc.ptc_stage_amplitude_K

    assert abs(fitted.heater_to_thermometer.frequency_response(omega)) == pytest.approx(
        abs(truth.heater_to_thermometer.frequency_response(omega)), rel=0.1)
    assert line(fitted) == pytest.approx(line(truth), rel=0.1)
    assert fitted.heater_to_thermometer.dc_gain == pytest.approx(truth.heater_to_thermometer.dc_gain, rel=0.15)
    assert fitted.name == "identified at 12 K"
