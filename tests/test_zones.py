"""Zones (control.zones): checked tables, selection by the setpoint in use, bumpless crossings, reloads,
each zone's heater limit, and the daemon's status and record (virtual time)."""

import dataclasses
import re

import numpy as np
import pytest

from cryod.config import load_config
from cryod.control.closed_loop import Segment, run_program
from cryod.control.pi import PiGains
from cryod.control.regulator import HeaterPowerOutput, Regulator
from cryod.control.zones import Zone, ZoneTable
from cryod.model import TEMPERATURE_MODEL_PATH
from cryod.service.daemon_status import DaemonStatus, status_json
from cryod.yaml_source import FileFormatError
from tests.conftest import CONFIG
from tests.example_config import with_zone_table
from tests.loop_doubles import example_curves, make_loop

TABLE = """  zones:
    - upper_K: 4.6
      pi: {proportional_W_per_K: 5.0, integral_W_per_K_s: 0.1}
      max_heater_power_W: 0.2
    - upper_K: 20.0
      pi: {proportional_W_per_K: 50.0, integral_W_per_K_s: 1.0}
      feedforward_model: zone-model.yaml
"""


def configured(tmp_path, table=TABLE, *replacements):
    """The example configuration with ``table`` under control: (path, text)."""
    return with_zone_table(tmp_path, table, *replacements)


def line_of(text, fragment, after=0):
    return next(number for number, line in enumerate(text.splitlines(), 1) if number > after and fragment in line)


# -- the table in the configuration ---------------------------------------------------------
def test_a_table_is_read_with_its_models_and_limits(tmp_path):
    path, _ = configured(tmp_path)
    zones = load_config(path).control.zones
    assert [zone.upper_K for zone in zones.zones] == [4.6, 20.0]
    assert zones.zones[0].gains == PiGains(5.0, 0.1) and zones.zones[0].max_heater_power_W == 0.2
    assert zones.zones[1].feedforward_model.operating_point.flange_temperature_K == 4.23
    assert zones.zones[1].max_heater_power_W is None
    assert load_config(CONFIG / "cryod.yaml").control.zones is None


def test_a_table_in_its_own_file_is_included_and_its_errors_name_that_file(tmp_path):
    table_path = tmp_path / "zones.yaml"
    table_path.write_text("zones:\n" + "\n".join(line[2:] for line in TABLE.splitlines()[1:]) + "\n")
    path, _ = configured(tmp_path, "  zones: zones.yaml\n")
    assert load_config(path).control.zones.zones[1].gains == PiGains(50.0, 1.0)
    table_path.write_text(table_path.read_text().replace("integral_W_per_K_s: 1.0", "integral_W_per_K_s: 0"))
    with pytest.raises(FileFormatError) as caught:
        load_config(path)
    assert caught.value.source == str(table_path) and caught.value.line == 6
    assert caught.value.key == "zones[1].pi.integral_W_per_K_s"


@pytest.mark.parametrize("old, new, key, reason", [
    ("    - upper_K: 20.0", "    - upper_K: 4.5", "control.zones[1].upper_K", "not above the previous zone's"),
    ("    - upper_K: 20.0", "    - upper_K: 19.0", "control.zones[1].upper_K", "ends below control.setpoint_max_K"),
    ("    - upper_K: 4.6", "    - upper_K: 3.0", "control.zones[0].upper_K", "at or below control.setpoint_min_K"),
    ("{proportional_W_per_K: 5.0,", "{proportional_W_per_K: 0,", "control.zones[0].pi.proportional_W_per_K",
     "greater than 0"),
    ("integral_W_per_K_s: 1.0}", "integral_W_per_K_s: -1.0}", "control.zones[1].pi.integral_W_per_K_s",
     "greater than 0"),
    ("feedforward_model: zone-model.yaml", "feedforward_model: missing.yaml", "control.zones[1].feedforward_model",
     "controller model not usable"),
    ("feedforward_model: zone-model.yaml", f"feedforward_model: {TEMPERATURE_MODEL_PATH}",
     "control.zones[1].feedforward_model", "temperature-dependent cryostat"),
    ("max_heater_power_W: 0.2", "max_heater_power_W: 0.6", "control.zones[0].max_heater_power_W",
     "above the heater's R * I_max^2"),
    ("max_heater_power_W: 0.2", "max_heater_power_W: 0.2\n      derivative: 1", "control.zones[0].derivative",
     "unknown key"),
    ("  zones:\n", "  zones: []\n  unused:\n", "control.zones", "at least one zone"),
])
def test_bad_tables_are_refused_at_file_line_and_key(tmp_path, old, new, key, reason):
    path, text = configured(tmp_path, TABLE, (old, new))
    with pytest.raises(FileFormatError) as caught:
        load_config(path)
    error = caught.value
    assert error.source == str(path) and error.key == key, str(error)
    assert reason in error.reason, str(error)
    start = line_of(text, "  zones:")
    item = re.search(r"zones\[(\d+)\]", key)
    if item is not None:
        for _ in range(int(item.group(1)) + 1):
            start = line_of(text, "- upper_K", after=start)
    assert error.line == line_of(text, key.split(".")[-1].split("[")[0], after=start - 1), str(error)


# -- the regulator --------------------------------------------------------------------------
def regulator_with(tmp_path, table=TABLE, ramp_K_per_min=0.0):
    config = load_config(configured(tmp_path, table)[0])
    control = dataclasses.replace(config.control, ramp_K_per_min=ramp_K_per_min)
    return Regulator(control, HeaterPowerOutput(config.heater.max_power_w)), config


def test_the_zone_is_the_one_holding_the_setpoint_in_use(tmp_path):
    table = ZoneTable((Zone(6.5, PiGains(1.0, 0.1)), Zone(10.0, PiGains(2.0, 0.1)), Zone(25.0, PiGains(3.0, 0.1))))
    assert [table.index_for(t) for t in (3.0, 6.5, 6.500001, 10.0, 24.0, 30.0)] == [0, 0, 1, 1, 2, 2]
    regulator, _ = regulator_with(tmp_path, ramp_K_per_min=0.0)
    regulator.close_loop(0.0, flange_K=4.3, ptc_stage_K=3.3, present_power_w=0.0)
    assert regulator.zone_index == 1          # the step goes straight to the setpoint, 5 K: zone 2
    assert regulator.term("pi").controller.gains == PiGains(50.0, 1.0)
    regulator.ramp.target_K = 4.4
    regulator.step(0.08, 0.08, flange_K=4.3, ptc_stage_K=3.3)
    assert regulator.zone_index == 0 and regulator.term("pi").controller.gains == PiGains(5.0, 0.1)
    assert [event.split(";")[0] for event in regulator.zone_events()] == [
        "zone 2 (up to 20 K): Kp 50 W/K, Ki 1 W/(K s), feedforward model zone-model.yaml, heater up to R * I_max^2",
        "zone 1 (up to 4.6 K): Kp 5 W/K, Ki 0.1 W/(K s), feedforward model of control.feedforward, "
        "heater up to 0.2 W"]
    assert regulator.zone_events() == []


def test_crossing_a_zone_during_a_ramp_is_bumpless(reference_model):
    """Gains ten times apart: switched with the error of a ramp, they would jump the heater by 45 W/K times it;
    handed over, the crossing tick moves the heater as the new gains alone would (the integral takes the rest)."""
    zones = ZoneTable((Zone(4.6, PiGains(5.0, 0.1)), Zone(20.0, PiGains(50.0, 1.0))))
    run = run_program(reference_model, [Segment(0.0, setpoint_K=5.0)], 120.0, gains=PiGains(5.0, 0.1),
                      heater_max_w=0.5, ramp_K_per_min=1.0, noise=False, initial_heater_power_w=0.0, zones=zones)
    k = int(np.flatnonzero(run.setpoint_K > 4.6)[0])
    error = run.setpoint_K - run.flange_K
    assert 45.0 * abs(error[k - 1]) > 0.005                # what a switch with a bump would do
    assert 0.0 < run.heater_w[k - 1] < 0.5 and 0.0 < run.heater_w[k] < 0.5
    handed_over = 50.0 * (error[k] - error[k - 1]) + 1.0 * error[k] * 0.08
    assert run.heater_w[k] - run.heater_w[k - 1] == pytest.approx(handed_over, abs=1e-12)
    integral = run.control["pi_integral_W"]
    assert integral[k] - integral[k - 1] == pytest.approx(-45.0 * error[k - 1] + 1.0 * error[k] * 0.08, abs=1e-12)


def test_without_zones_a_run_is_todays_and_one_zone_with_the_same_gains_changes_nothing(reference_model):
    gains = PiGains(10.0, 0.2)
    segments = [Segment(0.0, setpoint_K=5.0), Segment(200.0, setpoint_K=4.6)]
    plain = run_program(reference_model, segments, 400.0, gains=gains, heater_max_w=0.5, ramp_K_per_min=2.0)
    zoned = run_program(reference_model, segments, 400.0, gains=gains, heater_max_w=0.5, ramp_K_per_min=2.0,
                        zones=ZoneTable((Zone(25.0, gains),)))
    np.testing.assert_array_equal(plain.heater_w, zoned.heater_w)


def test_a_reload_changes_the_zone_in_use_bumplessly_and_without_zones_returns_to_control_pi(tmp_path):
    regulator, config = regulator_with(tmp_path)
    regulator.close_loop(0.0, flange_K=4.998, ptc_stage_K=3.3, present_power_w=0.1)
    for tick in range(1, 50):
        regulator.step(0.08 * tick, 0.08, flange_K=4.998 + 2e-5 * tick, ptc_stage_K=3.3)
    regulator.zone_events()
    controller = regulator.term("pi").controller
    before = controller.output_w
    assert 0.0 < before < config.heater.max_power_w
    faster = config.control.zones.zones[1]
    table = dataclasses.replace(config.control.zones, zones=(config.control.zones.zones[0],
                                                             dataclasses.replace(faster, gains=PiGains(80.0, 2.0))))
    regulator.reconfigure(dataclasses.replace(config.control, zones=table))
    assert controller.gains == PiGains(80.0, 2.0)
    assert controller.proportional_w + controller.integral_w == pytest.approx(before, abs=1e-12)
    assert regulator.zone_events()[0].startswith("zone 2 (up to 20 K): Kp 80 W/K")
    regulator.reconfigure(dataclasses.replace(config.control, zones=None))
    assert controller.gains == config.control.term("pi") and regulator.zone is None
    assert regulator.zone_events() == ["no zones (reload): control.pi and control.feedforward at every temperature"]
    assert controller.proportional_w + controller.integral_w == pytest.approx(before, abs=1e-12)


def test_each_zone_holds_the_heater_within_its_own_limit(tmp_path):
    regulator, config = regulator_with(tmp_path)
    regulator.ramp.target_K = 4.5                                   # zone 1: at most 0.2 W
    regulator.close_loop(0.0, flange_K=4.25, ptc_stage_K=3.3, present_power_w=0.0)
    step = regulator.step(0.08, 0.08, flange_K=4.25, ptc_stage_K=3.3)
    assert regulator.zone_index == 0
    step = regulator.step(0.16, 0.08, flange_K=4.0, ptc_stage_K=3.3)
    assert step.power_w == pytest.approx(0.2) and step.limited
    regulator.ramp.target_K = 6.0                                   # zone 2: R * I_max^2 = 0.5 W
    step = regulator.step(0.24, 0.08, flange_K=4.0, ptc_stage_K=3.3)
    assert regulator.zone_index == 1 and step.power_w == pytest.approx(config.heater.max_power_w) and step.limited


# -- the daemon: status and record ----------------------------------------------------------
def test_the_daemon_shows_the_zone_in_its_status_and_records_each_change(tmp_path, reference_model):
    path, _ = configured(tmp_path, TABLE, ("  ramp_K_per_min: 0.0 ", "  ramp_K_per_min: 1.0 "))
    config = load_config(path)
    loop, _, _, rows, events = make_loop(reference_model, example_curves(), config)
    assert loop.run(duration_s=60.0, manage_gc=False) == 0
    zone_events = [event.message for event in events if event.kind == "zone"]
    assert zone_events[0].startswith("zone 2 (up to 20 K)") and zone_events[0].endswith("; start")   # setpoint 5 K
    assert re.search(r"^zone 1 \(up to 4\.6 K\).*; loop closed at 4\.2\d* K$", zone_events[1])     # the ramp's start
    assert re.search(r"^zone 2 \(up to 20 K\).*; setpoint in use 4\.6\d* K$", zone_events[-1])
    status = status_json(DaemonStatus(loop=loop.status))
    assert status["zone"] == 2 and status["zone_upper_K"] == 20.0
    assert "(zone 2)" in loop.status.one_line()
    crossing = next(index for index, row in enumerate(rows) if row.setpoint_K > 4.6)
    assert max(row.heater_W for row in rows[:crossing]) <= 0.2 + 1e-12      # zone 1's limit
    plain, _, _, _, plain_events = make_loop(reference_model, example_curves(), load_config(CONFIG / "cryod.yaml"))
    plain.run(duration_s=5.0, manage_gc=False)
    assert "zone" not in status_json(DaemonStatus(loop=plain.status)) and not [event for event in plain_events if event.kind == "zone"]


# -- the setpoint the heater can hold, judged in its zone -------------------------------------
def test_a_setpoints_warning_uses_the_model_and_heater_limit_of_the_zone_holding_it(tmp_path):
    """Zone 1 (to 6.5 K) limits the heater to 0.2 W; zone 2's model has a heater path four times the shipped
    model's. 6 K needs about 260 mW by the shipped model: holdable with R I_max^2 = 0.5 W, not within zone 1's
    limit. 16 K needs 1726 mW by the shipped model and a quarter of that by zone 2's: holdable there. The
    regulator runs on the zone's model and limit, so that is what the warning must judge by."""
    from cryod.control.setpoint_reach import setpoint_warning

    path, _ = configured(tmp_path, TABLE, ("    - upper_K: 4.6", "    - upper_K: 6.5"))
    shipped = (CONFIG / "model.yaml").read_text()
    assert "numerator: [338.42, 6.8182]" in shipped
    (tmp_path / "zone-model.yaml").write_text(shipped.replace("numerator: [338.42, 6.8182]",
                                                              "numerator: [1353.68, 27.2728]"))
    config = load_config(path)
    heater_w = config.heater.max_power_w
    assert heater_w == pytest.approx(0.5)
    plain = dataclasses.replace(config.control, zones=None)
    assert setpoint_warning(plain, 6.0, heater_w) is None
    assert setpoint_warning(plain, 16.0, heater_w).startswith("setpoint 16 K needs about 1726 mW")
    in_zone_1 = setpoint_warning(config.control, 6.0, heater_w)
    assert in_zone_1.startswith("setpoint 6 K needs about 260 mW of heater power in steady state (zone 1: ")
    assert "above zone 1's heater limit, max_heater_power_W = 200 mW" in in_zone_1
    assert setpoint_warning(config.control, 16.0, heater_w) is None
    in_zone_2 = setpoint_warning(config.control, 20.0, heater_w)
    assert in_zone_2.startswith("setpoint 20 K needs about 578 mW of heater power in steady state "
                                "(zone 2: zone-model.yaml), above the heater's top, R I_max^2 = 500 mW"), in_zone_2


def test_terms_are_told_of_a_zone_entered_by_the_setpoint_not_of_a_start_or_a_reload(tmp_path):
    """What a term learned of the cryostat (the feedforward's plant) belongs to an operating point: the setpoint
    moving into another zone moves it, a reload that redraws the zones around an unmoved setpoint does not."""
    regulator, config = regulator_with(tmp_path)
    told = []
    regulator.term("feedforward").enter_zone = told.append
    regulator.close_loop(0.0, flange_K=4.998, ptc_stage_K=3.3, present_power_w=0.1)      # 5 K: zone 2 from the start
    regulator.step(0.08, 0.08, flange_K=4.998, ptc_stage_K=3.3)
    assert regulator.zone_index == 1 and told == []
    regulator.ramp.target_K = 4.4
    regulator.step(0.16, 0.08, flange_K=4.998, ptc_stage_K=3.3)
    assert regulator.zone_index == 0 and told == [0]
    zones = config.control.zones
    moved = dataclasses.replace(zones, zones=(dataclasses.replace(zones.zones[0], upper_K=4.3), zones.zones[1]))
    regulator.reconfigure(dataclasses.replace(config.control, zones=moved))
    assert regulator.zone_index == 1 and told == [0]
    regulator.close()
