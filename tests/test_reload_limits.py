"""A reload that would break a limit is refused, in every state of the loop, naming file, line and key.

The daemon runs in process on virtual time on the simulated bench. Operator commands and reloads
are handed to the loop at given rows; a refused reload keeps the running configuration whole and
says why at the key of the new file it concerns, and the loop goes on as before.
"""

import dataclasses

import numpy as np
import pytest

from cryod.control.ramp import MIN_RATE_K_PER_MIN, SetpointRamp
from tests.reload_drills import ReloadDrill

#: The limits of the reload in the adversarial run: below a setpoint of 12 K in use.
LOWER_LIMITS = (("  setpoint_max_K: 20.0", "  setpoint_max_K: 8.0"), ("  flange_max_K: 25.0", "  flange_max_K: 10.0"))


def test_a_reload_below_the_setpoint_in_use_during_a_ramp_is_refused_and_the_ramp_goes_on(tmp_path):
    """Setpoint 12 K, ramp 0.1 K/min, setpoint 5 K: the setpoint in use is still about 12 K when a reload
    lowers setpoint_max_K to 8 K and flange_max_K to 10 K. Refused at setpoint_max_K; nothing changes."""
    drill = ReloadDrill(tmp_path, {
        10: lambda d: d.command("up", "setpoint", 12.0),
        20: lambda d: d.command("rate", "ramp", 0.1),
        30: lambda d: d.command("down", "setpoint", 5.0),
        100: lambda d: d.reload("lower", LOWER_LIMITS),
    })
    assert drill.run(30.0).exit_code == 0
    assert all(drill.answer(label).ok for label in ("up", "rate", "down"))
    message = drill.refusal_at("lower", "control.setpoint_max_K", "8 K is below the setpoint in use, 11.99")
    assert "ramping to 5 K at 0.1 K/min" in message and "cryod ctl ramp 0" in message
    running = drill.loop.config
    assert running.control.setpoint_max_K == 20.0 and running.safety.flange_max_K == 25.0   # kept whole
    assert drill.loop.checks.flange_max_K == 25.0
    setpoints = np.array([row.setpoint_K for row in drill.rows[110:]], dtype=float)
    assert np.all(np.diff(setpoints) < 0) and setpoints[-1] < 11.99          # the ramp goes on, downward
    events = [text for _, text in drill.record.events if "reload refused" in text]
    assert len(events) == 1 and "control.setpoint_max_K" in events[0]


def test_the_same_reload_is_taken_once_the_ramp_has_stepped_below_the_new_limit(tmp_path):
    drill = ReloadDrill(tmp_path, {
        10: lambda d: d.command("up", "setpoint", 12.0),
        20: lambda d: d.command("rate", "ramp", 0.1),
        30: lambda d: d.command("down", "setpoint", 5.0),
        100: lambda d: d.command("steps", "ramp", 0.0),
        110: lambda d: d.reload("lower", LOWER_LIMITS),
    })
    assert drill.run(20.0).exit_code == 0
    assert drill.answer("lower").ok, drill.answer("lower").message
    assert drill.loop.config.control.setpoint_max_K == 8.0 and drill.loop.checks.flange_max_K == 10.0


@pytest.mark.parametrize("state, before, reload_row, fragment", [
    # regulating at 12 K with steps (the heater at its top: 12 K is more than it can hold)
    ("closed", {10: lambda d: d.command("up", "setpoint", 12.0)}, 11, "8 K is below the setpoint in use, 12 K"),
    # a setpoint given while the loop still holds the heater off for valid readings
    ("holding", {1: lambda d: d.command("up", "setpoint", 12.0)}, 2, "8 K is below the setpoint asked for, 12 K"),
    # a sensor overflow of three readings puts the loop in recovery; it resumes at 12 K
    ("recovering", {10: lambda d: d.command("up", "setpoint", 12.0),
                    99: lambda d: d.opener.bench.ptc_stage_dmm.inject_overflow(3)}, 104,
     "8 K is below the setpoint in use, 12 K"),
])
def test_a_reload_below_the_setpoint_is_refused_while_the_loop_aims_at_it(tmp_path, state, before, reload_row,
                                                                            fragment):
    drill = ReloadDrill(tmp_path, {**before, reload_row: lambda d: d.reload("lower", LOWER_LIMITS)})
    assert drill.run(20.0).exit_code == 0
    assert str(drill.rows[reload_row - 1].state).startswith(state)
    drill.refusal_at("lower", "control.setpoint_max_K", fragment)
    assert drill.loop.config.control.setpoint_max_K == 20.0


def test_a_ramp_rate_above_a_new_ramp_limit_is_refused_in_every_state(tmp_path):
    """A rate set by command outlives a heater-off: the next setpoint would ramp at it."""
    drill = ReloadDrill(tmp_path, {
        10: lambda d: d.command("rate", "ramp", 5.0),
        20: lambda d: d.command("off", "heater-off"),
        30: lambda d: d.reload("slower", [("  max_ramp_K_per_min: 10.0", "  max_ramp_K_per_min: 1.0")]),
    })
    assert drill.run(10.0).exit_code == 0
    drill.refusal_at("slower", "control.max_ramp_K_per_min", "1 K/min is below the ramp rate in use, 5 K/min")


def test_manual_and_off_use_no_setpoint_so_lower_limits_are_taken_and_the_next_setpoint_meets_them(tmp_path):
    drill = ReloadDrill(tmp_path, {
        10: lambda d: d.command("up", "setpoint", 12.0),
        20: lambda d: d.command("manual", "manual", 0.01),
        30: lambda d: d.reload("lower in manual", LOWER_LIMITS),
        40: lambda d: d.command("refused", "setpoint", 12.0),
        50: lambda d: d.command("off", "heater-off"),
        60: lambda d: d.command("again", "setpoint", 7.0),
    })
    assert drill.run(20.0).exit_code == 0
    assert drill.answer("lower in manual").ok
    refused = drill.answer("refused")
    assert not refused.ok and "outside 3..8 K" in refused.message
    assert drill.answer("again").ok
    assert max(row.setpoint_K for row in drill.rows[70:]) <= 8.0


def test_a_setpoint_given_while_recovering_from_off_starts_from_the_flange_not_from_an_old_setpoint(tmp_path):
    """Heater off at 12 K, limits lowered, a fault, then setpoint 5 K with a ramp: when the loop resumes it
    closes from T2 and 0 W; the 12 K of before the heater-off is not the setpoint in use again."""
    drill = ReloadDrill(tmp_path, {
        10: lambda d: d.command("up", "setpoint", 12.0),
        20: lambda d: d.command("rate", "ramp", 0.5),
        30: lambda d: d.command("off", "heater-off"),
        40: lambda d: d.reload("lower", LOWER_LIMITS),
        50: lambda d: d.opener.bench.ptc_stage_dmm.inject_overflow(3),
        52: lambda d: d.command("down", "setpoint", 5.0),
    })
    assert drill.run(20.0).exit_code == 0
    assert drill.answer("lower").ok
    assert drill.answer("down").message == "setpoint 5 K, applied once readings are valid"
    resumed = [row for row in drill.rows[53:] if str(row.state).startswith("closed")]
    assert resumed and max(row.setpoint_K for row in resumed) < 8.0
    assert resumed[0].setpoint_K == pytest.approx(resumed[0].T2_K, abs=0.01)


def test_an_over_temperature_limit_below_the_flange_now_is_refused_instead_of_stopping_the_daemon(tmp_path):
    """Heater off, the flange near 4.26 K: a reload with flange_max_K 4 K would stop the daemon (exit 3) at the
    next reading; refused at safety.flange_max_K, and the daemon runs on."""
    cold = [("  setpoint_K: 5.0", "  setpoint_K: null"), ("  setpoint_max_K: 20.0", "  setpoint_max_K: 3.9"),
            ("  flange_max_K: 25.0", "  flange_max_K: 4.0")]
    drill = ReloadDrill(tmp_path, {
        10: lambda d: d.command("off", "heater-off"),
        20: lambda d: d.reload("cold", cold),
    })
    assert drill.run(10.0).exit_code == 0
    drill.refusal_at("cold", "safety.flange_max_K", "4 K is below T2 now, 4.2")
    assert "over_temperature" in drill.answer("cold").message
    assert drill.loop.checks.flange_max_K == 25.0


def test_an_over_temperature_limit_below_the_flange_while_holding_holds_as_a_start_would(tmp_path):
    """While the heater is held off for valid readings, a lower limit only holds it off longer (as a start with
    that configuration would): taken, and said once per hold."""
    cold = [("  setpoint_K: 5.0", "  setpoint_K: null"), ("  setpoint_max_K: 20.0", "  setpoint_max_K: 3.9"),
            ("  flange_max_K: 25.0", "  flange_max_K: 4.0")]
    drill = ReloadDrill(tmp_path, {1: lambda d: d.reload("cold", cold)}, start=cold[:1])
    assert drill.run(5.0).exit_code == 0
    assert drill.answer("cold").ok
    assert {str(row.state) for row in drill.rows[2:]} == {"holding"}
    assert any("heater held off while holding" in text for _, text in drill.record.events)


def test_a_reload_needing_a_restart_names_the_section_with_file_and_line(tmp_path):
    drill = ReloadDrill(tmp_path, {10: lambda d: d.reload("heater", [("  resistance_ohm: 50.0",
                                                                       "  resistance_ohm: 25.0")])})
    assert drill.run(5.0).exit_code == 0
    drill.refusal_at("heater", "heater", "changes to heater need a restart")
    assert dataclasses.asdict(drill.loop.config.heater)["resistance_ohm"] == 50.0


def test_a_ramp_too_slow_to_move_the_setpoint_is_refused(tmp_path):
    """``ramp 1e-320`` added nothing to the setpoint at each tick and froze it where the loop closed."""
    drill = ReloadDrill(tmp_path, {
        10: lambda d: d.command("frozen", "ramp", 1e-320),
        11: lambda d: d.command("slowest", "ramp", MIN_RATE_K_PER_MIN),
        20: lambda d: d.command("up", "setpoint", 5.5),
    })
    assert drill.run(10.0).exit_code == 0
    frozen = drill.answer("frozen")
    assert not frozen.ok
    assert frozen.message == ("ramp refused: 1e-320 K/min is too slow to move the setpoint: give 0 for steps or at "
                              "least 1e-06 K/min")
    assert drill.answer("slowest").ok and drill.answer("up").ok
    setpoints = np.array([row.setpoint_K for row in drill.rows[21:]], dtype=float)
    assert np.all(np.diff(setpoints) > 0)                # the slowest ramp still moves it, every tick


def test_the_slowest_ramp_moves_the_setpoint_at_every_tick_of_any_configuration():
    """At the shortest loop period a configuration takes and the highest limit, a step of the slowest ramp is
    thousands of floating-point steps."""
    step_K = MIN_RATE_K_PER_MIN / 60.0 * 0.01
    assert step_K > 1000 * np.spacing(400.0)
    ramp = SetpointRamp(399.9, MIN_RATE_K_PER_MIN)
    ramp.target_K = 400.0
    assert ramp.advance(0.01) > 399.9
    with pytest.raises(ValueError, match="too slow to move the setpoint"):
        SetpointRamp(5.0, 1e-300)
