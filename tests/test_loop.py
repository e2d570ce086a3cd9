"""The control loop's scheduling, control, commands, reload and fault handling (virtual time)."""

import dataclasses
import math
import threading

import numpy as np
import pytest

from drivers.clock import VirtualClock
from cryod.config import load_config
from cryod.control.pi import PiGains
from cryod.records.columns import Row
from cryod.service.commands import Command
from cryod.service.loop import HEATER_OFF_ROW_SPACING_S, ControlLoop
from drivers.errors import BadReply, ConnectionLost, HeaterCompliance, InstrumentTimeout, OverflowReading
from simulated_hw.cryostat import SimulatedCryostat
from tests.conftest import CONFIG
from tests.loop_doubles import DirectInstruments, example_curves, heater_off_rows, make_loop, tick_rows


@pytest.fixture(scope="module")
def curves():
    return example_curves()


@pytest.fixture(scope="module")
def base_config():
    return load_config(CONFIG / "cryod.yaml")


def test_regulates_to_setpoint_with_contract_columns(reference_model, curves, base_config):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    assert loop.run(duration_s=900.0, manage_gc=False) == 0
    assert not heater_off_rows(rows) and events[-1].kind == "stop"      # a stop's off is its event
    assert len(rows) == pytest.approx(900 / 0.08, abs=1)
    assert loop.schema.names[:5] == ("time_s", "T2_K", "T5_K", "heater_W", "setpoint_K")
    assert {"pi_proportional_W", "pi_integral_W", "ff_W", "ff_phase_rad"} <= set(rows[-1].control) \
        <= set(loop.schema.names)
    times = np.array([row.time_s for row in rows])
    np.testing.assert_allclose(np.diff(times), 0.08, atol=1e-9)   # absolute deadlines, no drift
    late = [row for row in rows if row.time_s > 600.0]
    flange = np.array([row.T2_K for row in late])
    assert np.mean(flange) == pytest.approx(5.0, abs=3e-4)
    heater = np.array([row.heater_W for row in rows])
    assert heater.min() >= 0.0 and heater.max() <= base_config.heater.max_power_w
    # the first valid_readings_to_resume ticks hold the heater off
    assert [row.state for row in rows[:5]] == ["holding"] * 5 and rows[5].state.startswith("closed")
    assert instruments.cryostat.heater_power_w == 0.0          # heater off at the end of the run
    assert any("resumed" in event.text for event in events)


def test_late_cycles_skip_to_the_next_deadline_and_a_streak_fades_the_feedforward_out_not_the_heater(
        reference_model, curves, base_config):
    """Late cycles with fresh readings are no fault: the loop regulates on through a streak of ten; after
    loop.overrun_streak_limit (5) in a row the feedforward fades out, and back in once the cycles kept their
    deadlines for 10 s, each said in the record."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.measure_delays = {100: 0.2, 101: 0.05}                      # one cycle 2.9 periods long
    instruments.measure_delays.update({3000 + k: 0.1 for k in range(10)})  # then a streak, feedforward locked
    code = loop.run(duration_s=600.0, manage_gc=False)
    times = np.array([row.time_s for row in rows])
    steps = np.diff(times)
    assert steps.min() >= 0.08 - 1e-9                       # never a burst to catch up
    assert np.isclose(steps, 0.24).sum() >= 1               # skipped two deadlines after the long cycle
    overruns = [event.text for event in events if event.kind == "overrun"]
    assert overruns[0].endswith("2 deadline(s) skipped")
    assert 200.0 < float(overruns[0].split("cycle ended ")[1].split(" ms")[0]) < 240.0   # the 0.2 s delay + reading
    assert len(overruns) == loop.timing.summary()["overruns"] >= 10
    assert code == 0 and loop.last_fault is None and not heater_off_rows(rows)
    timing = [event.text for event in events if event.kind == "timing"]
    assert len(timing) == 2 and timing[0].startswith("timing: 5 cycles in a row ended after the next deadline")
    assert "the feedforward fades back in" in timing[1]
    rows = tick_rows(rows)
    scale = np.array([(row.control or {}).get("ff_scale", 0.0) for row in rows])
    streak = next(index for index, row in enumerate(rows) if row.time_s > times[0] + 3000 * 0.08)
    assert scale[streak - 1] == 1.0 and all(row.heater_W > 0.0 for row in rows[streak:streak + 200])
    assert scale[streak + 80] == 0.0                        # faded out within its 5 s
    assert scale[-1] == 1.0 and loop.on_time                # and back


def test_readings_too_old_to_set_the_heater_from_are_a_fault_it_recovers_from(reference_model, curves, base_config):
    """A reading that comes back 0.6 s after its trigger (safety.max_reading_age_s 0.5): the heater is not set from
    it but switched off, and the loop resumes from fresh valid readings."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.measure_delays = {1000: 0.6}
    assert loop.run(duration_s=200.0, manage_gc=False) == 0
    faults = [event.text for event in events if event.kind == "fault"]
    assert len(faults) == 1 and faults[0].startswith("fault: readings_too_old: the readings were 0.63")
    assert "(safety.max_reading_age_s 0.5)" in faults[0]
    ticks = tick_rows(rows)
    fault_row = next(row for row in ticks if row.state == "fault:readings_too_old")
    assert fault_row.heater_W > 0.0                      # what the supply had during that tick
    assert heater_off_rows(rows)[0].heater_W == 0.0
    after = ticks[ticks.index(fault_row) + 1:]
    assert [row.state for row in after[:5]] == ["recovering"] * 5 and after[5].state.startswith("closed")


@pytest.mark.parametrize("error, cause", [
    (InstrumentTimeout("flange DMM", "no reply within 1 s"), "instrument_timeout"),
    (ConnectionLost("heater", "socket closed"), "connection_lost"),
    (OverflowReading("flange DMM", "overflow", reply="+9.9E37"), "sensor_overflow"),
])
def test_transient_fault_heater_off_at_once_then_resume_after_valid_readings(reference_model, curves, base_config,
                                                                              error, cause):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.measure_faults = {2000: error, 2001: error, 2002: error}
    assert loop.run(duration_s=200.0, manage_gc=False) == 0
    # the fault tick's row carries the power the supply had during it; a row of its own at the instant the
    # supply confirmed the off carries the 0 W (written to the supply in the tick that found the fault; here,
    # where the off takes no time, two record steps after the fault's row, so that they print apart)
    off = rows[rows.index(tick_rows(rows)[2000]) + 1]
    fault_time = tick_rows(rows)[2000].time_s
    assert heater_off_rows([off]) and off.state == f"fault:{cause}" and off.heater_W == 0.0
    assert (off.heater_set_s, 0.0) in instruments.heater_log and fault_time <= off.heater_set_s < fault_time + 0.08
    assert off.time_s == max(off.heater_set_s, fault_time + HEATER_OFF_ROW_SPACING_S)
    assert sum(row.state.startswith("fault") for row in heater_off_rows(rows)) == 1    # off since then
    applied = tick_rows(rows)[1999].heater_W
    rows = tick_rows(rows)
    fault_rows = [i for i, row in enumerate(rows) if row.state == f"fault:{cause}"]
    assert len(fault_rows) == 3 and fault_rows[0] == 2000
    assert applied > 0.0 and rows[2000].heater_W == applied
    assert all(rows[i].heater_W == 0.0 for i in fault_rows[1:])
    if cause in ("instrument_timeout", "connection_lost"):     # the tick that reconnects takes no reading
        assert fault_rows == [2000, 2002, 2003] and rows[2001].state == "recovering"
        assert math.isnan(rows[2001].T2_K) and rows[2001].heater_W == 0.0
    last = fault_rows[-1]
    after = rows[last + 1:last + 6]
    assert all(row.state == "recovering" and row.heater_W == 0.0 and row.T2_K > 0.0 for row in after)
    assert rows[last + 6].state.startswith("closed") and rows[last + 6].heater_W > 0.0
    assert any(event.text.startswith("fault: " + cause) for event in events)
    if cause in ("instrument_timeout", "connection_lost"):
        assert instruments.reconnects >= 1


def test_recovery_timeout_exits_4(reference_model, curves, base_config):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.measure_faults = {k: InstrumentTimeout("flange DMM", "no reply") for k in range(100, 2000)}
    assert loop.run(duration_s=200.0, manage_gc=False) == 4
    assert "not recovered within 60 s" in str(loop.last_fault)
    assert cryostat.heater_power_w == 0.0


def test_over_temperature_exits_3_with_heater_off(reference_model, curves, base_config):
    config = dataclasses.replace(base_config, safety=dataclasses.replace(base_config.safety, flange_max_K=4.6),
                                 control=dataclasses.replace(base_config.control, setpoint_max_K=4.5))
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, config)
    loop.submit(Command("manual", 0.3))                     # heat open loop until the limit trips
    assert loop.run(duration_s=600.0, manage_gc=False) == 3
    assert loop.last_fault.cause == "over_temperature" and "T2" in loop.last_fault.message
    assert rows[-2].heater_W == 0.3 and rows[-2].T2_K > 4.6 and rows[-2].state == "fault:over_temperature"
    assert rows[-1].heater_W == 0.0 and rows[-1].state == "fault:over_temperature"
    assert cryostat.heater_power_w == 0.0


def test_sensor_out_of_calibration_and_stale_readings(reference_model, curves, base_config):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.resistance_override = {500: (1.0, 3000.0)}                        # 1 ohm: far outside the curve
    instruments.resistance_override.update({1000 + k: (2800.0, 3000.0) for k in range(50)})  # frozen DMM
    assert loop.run(duration_s=120.0, manage_gc=False) == 0
    states = [row.state for row in tick_rows(rows)]
    assert states[500] == "fault:sensor_out_of_calibration"
    assert states[1049] == "fault:sensor_stale"
    assert states[-1].startswith("closed")


def test_heater_fault_exits_6(reference_model, curves, base_config):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.heater_faults = {50: HeaterCompliance("heater", "compliance reached: open heater?")}
    assert loop.run(duration_s=60.0, manage_gc=False) == 6
    assert loop.last_fault.cause == "heater_fault"
    assert cryostat.heater_power_w == 0.0


def test_a_long_stop_tick_writes_no_overrun_after_the_stop(reference_model, curves, base_config):
    """A heater fault found in a tick that ran long: the stop event is the loop's last word."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.measure_delays = {45: 0.5}             # the tick of the 40th setting (the first 5 hold)
    instruments.heater_faults = {40: HeaterCompliance("heater", "compliance reached: open heater?")}
    assert loop.run(duration_s=60.0, manage_gc=False) == 6
    assert events[-1].kind == "stop" and not any(event.kind == "overrun" for event in events)
    assert rows[-2].state == "fault:heater_fault" and rows[-1].heater_W == 0.0 and heater_off_rows(rows[-1:])


def test_unexpected_exception_turns_heater_off_and_propagates(reference_model, curves, base_config):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.measure_faults = {300: RuntimeError("bug")}
    with pytest.raises(RuntimeError):
        loop.run(duration_s=60.0, manage_gc=False)
    assert loop.exit_code == 1 and loop.last_fault.cause == "exception"
    assert cryostat.heater_power_w == 0.0


def test_a_stop_asked_for_while_the_tick_reads_sets_no_new_power(reference_model, curves, base_config):
    """A signal arriving while the loop waits for its readings: the tick ends in the stop, with the readings
    kept in its row, and the supply is told 0 W, not the tick's new power first."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    original = instruments.measure

    def measure_then_signal():
        reading = original()
        if instruments.measurements == 800:
            loop.request_stop("SIGUSR1 received", 138, "signal")
        return reading

    instruments.measure = measure_then_signal
    assert loop.run(duration_s=600.0, manage_gc=False) == 138
    asked_at = rows[-1].time_s
    assert [power for time_s, power in instruments.heater_log if time_s >= asked_at] == [0.0]
    assert rows[-1].heater_W == 0.0 and rows[-1].state == "stopped" and np.isfinite(rows[-1].T2_K)
    assert [str(event) for event in events if event.kind == "stop"] == ["stop: signal: SIGUSR1 received (exit 138)"]


def test_a_heater_held_off_from_outside_ends_in_the_stop_asked_for(reference_model, curves, base_config):
    """The stop's last resort switches the heater off from another thread; a setting the loop then still
    tries is refused, and the loop stops as asked (not as for a heater fault)."""
    from cryod.service.heater_guard import HeaterGuard

    clock = VirtualClock()
    instruments = DirectInstruments(SimulatedCryostat(reference_model, clock, seed=2), *curves, clock)
    guard = HeaterGuard(instruments)
    rows, events = [], []
    loop = ControlLoop(base_config, guard, *curves, clock,
                       emit=lambda item: (rows if isinstance(item, Row) else events).append(item))
    original = guard.set_heater_power

    def held_off_just_before_setting(power_w):
        if instruments.measurements == 800:         # between the loop's look at the stop and its setting
            loop.request_stop("SIGABRT received", 134, "signal")
            assert guard.hold_off("SIGABRT received", 1.0) is None
        return original(power_w)

    guard.set_heater_power = held_off_just_before_setting
    assert loop.run(duration_s=600.0, manage_gc=False) == 134
    assert instruments.heater_log[-1][1] == 0.0 and loop.last_fault.cause == "signal"
    assert guard.held_off == "SIGABRT received"


def test_stop_request_turns_heater_off(reference_model, curves, base_config):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    original = instruments.measure

    def measure_then_stop():
        if instruments.measurements == 800:
            loop.request_stop("SIGTERM received")
        return original()

    instruments.measure = measure_then_stop
    assert loop.run(duration_s=600.0, manage_gc=False) == 0
    assert len(rows) == 801 and loop.last_fault.cause == "stop_requested" and events[-1].kind == "stop"
    assert cryostat.heater_power_w == 0.0


def test_commands_are_checked_against_limits(reference_model, curves, base_config):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    answers = {}

    def measure_and_command():
        count = instruments.measurements
        script = {100: ("setpoint", 25.0), 101: ("ramp", 50.0), 102: ("manual", 0.6), 103: ("ramp", 1.0),
                  104: ("setpoint", 6.0), 3000: ("heater-off", None), 3500: ("manual", 0.05), 4000: ("setpoint", 5.5)}
        if count in script:
            answers[count] = loop.submit(Command(*script[count]))
        return DirectInstruments.measure(instruments)

    instruments.measure = measure_and_command
    loop.run(duration_s=400.0, manage_gc=False)
    assert not heater_off_rows(rows)          # a command's heater-off is in its tick's row
    assert not answers[100].ok and "outside 3..20 K" in answers[100].message
    assert not answers[101].ok and "max_ramp" in answers[101].message
    assert not answers[102].ok and "0..0.5 W" in answers[102].message
    assert answers[103].ok and answers[104].ok
    ramping = [row.setpoint_K for row in rows[200:300]]
    assert np.all(np.diff(ramping) > 0) and np.diff(ramping)[0] == pytest.approx(1.0 / 60 * 0.08)
    assert rows[3001].state == "off" and rows[3001].heater_W == 0.0
    assert rows[3501].state == "manual" and rows[3501].heater_W == 0.05
    assert rows[4001].state.startswith("closed")
    # bumpless: closing the loop from 50 mW manual continues from 50 mW
    first = rows[4001]
    assert first.control["pi_integral_W"] == pytest.approx(0.05, abs=1e-4)     # the integral takes the 50 mW over
    # and the rest is what acts from then on: the ramp's first step through Kp, the feedforward fading in
    assert first.heater_W == pytest.approx(0.05 + first.control["pi_proportional_W"] + first.control["ff_W"],
                                           abs=1e-4)
    assert abs(first.control["pi_proportional_W"]) < 0.02 and abs(first.control["ff_W"]) < 0.005


def test_reload_is_bumpless_and_refuses_restart_only_changes(quiet_reference_model, curves, base_config):
    """Doubling the gains while the error is large must not step the heater (PTC line off)."""
    loop, instruments, cryostat, rows, events = make_loop(quiet_reference_model, curves, base_config)
    control = base_config.control
    gains = control.term("pi")
    doubled = PiGains(2 * gains.proportional_w_per_K, 2 * gains.integral_w_per_K_s)
    new_gains = dataclasses.replace(base_config, control=dataclasses.replace(
        control, terms=tuple((name, doubled if name == "pi" else settings) for name, settings in control.terms)),
        source="new.yaml")
    moved_dmm = dataclasses.replace(base_config, instruments=dataclasses.replace(
        base_config.instruments, timeout_s=2.0), source="new.yaml")
    answers = {}

    def measure_and_reload():
        # reload with the output well inside its limits and a large error, where a bump cannot be clipped
        last = rows[-1] if rows else None
        if "gains" not in answers and last is not None and last.state == "closed" and last.heater_W < 0.3 \
                and last.setpoint_K - last.T2_K > 0.008:
            answers["gains"] = loop.submit(Command("reload", new_gains))
            answers["at"] = len(rows) + 1            # this tick makes row len(rows); the next applies it
        elif "gains" in answers and "dmm" not in answers:
            answers["dmm"] = loop.submit(Command("reload", moved_dmm))
        return DirectInstruments.measure(instruments)

    instruments.measure = measure_and_reload
    loop.run(duration_s=100.0, manage_gc=False)
    assert answers["gains"].ok and loop.regulator.terms[0].controller.gains == doubled
    assert not answers["dmm"].ok and "instruments" in answers["dmm"].message and "restart" in answers["dmm"].message
    at = answers["at"]
    assert rows[at].state == "closed" and rows[at].setpoint_K - rows[at].T2_K > 0.007
    before, after = rows[at - 1].heater_W, rows[at].heater_W
    # a non-bumpless change would add Kp_old * error > 0.07 W, unclipped (0.3 + 0.07 < 0.5 W);
    # the normal tick-to-tick change here is Kp times about 1 mK
    assert abs(after - before) < 0.03


@pytest.mark.parametrize("reload_at, state_then", [(200, "closed"), (310, "fault:instrument_timeout"), (335, "recovering")])
def test_no_reload_leaves_the_setpoint_in_use_outside_the_limits(reference_model, curves, base_config, reload_at,
                                                                  state_then):
    """Setpoint 15 K, then a DMM timeout, then a reload with setpoint_max_K 10: refused whether the loop is
    regulating or recovering from the fault (it would resume at 15 K, above the new limit)."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    narrowed = dataclasses.replace(base_config, control=dataclasses.replace(base_config.control, setpoint_max_K=10.0),
                                   source="narrowed.yaml")
    instruments.measure_faults = {k: InstrumentTimeout("flange DMM", "no reply") for k in range(300, 330)}
    answers = {}
    original = instruments.measure

    def measure():
        count = instruments.measurements
        if count == 100:
            answers["setpoint"] = loop.submit(Command("setpoint", 15.0))
        if count == reload_at:
            answers["reload"] = loop.submit(Command("reload", narrowed))
            answers["state"] = tick_rows(rows)[-1].state
        return original()

    instruments.measure = measure
    assert loop.run(duration_s=60.0, manage_gc=False) == 0
    rows = tick_rows(rows)
    assert answers["setpoint"].ok and answers["state"].startswith(state_then)
    assert not answers["reload"].ok and "15 K" in answers["reload"].message and "10 K" in answers["reload"].message
    assert loop.config.control.setpoint_max_K == 20.0 and rows[-1].setpoint_K <= 20.0
    assert rows[-1].state.startswith("closed")                 # resumed, within the limits still in force


@pytest.mark.parametrize("command, state, heater", [(("heater-off", None), "off", 0.0),
                                                    (("manual", 0.02), "manual", 0.02)])
def test_recovery_returns_to_the_mode_that_was_running(reference_model, curves, base_config, command, state, heater):
    """A transient fault after heater-off (or manual) must not bring regulation back."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    original = instruments.measure

    def measure():
        if instruments.measurements == 100:
            loop.submit(Command(*command))
        return original()

    instruments.measure = measure
    instruments.measure_faults = {500: InstrumentTimeout("flange DMM", "no reply")}
    assert loop.run(duration_s=60.0, manage_gc=False) == 0
    rows = tick_rows(rows)
    assert rows[499].state == state and rows[500].state == "fault:instrument_timeout"
    assert rows[-1].state == state and rows[-1].heater_W == heater


def test_a_fault_from_the_first_reading_is_logged_retried_and_bounded(reference_model, curves, base_config, caplog):
    """A DMM that answers badly from the start: warning, reconnects, exit 4 after the recovery timeout."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.measure_faults = {k: BadReply("flange DMM", "garbage") for k in range(100000)}
    with caplog.at_level("WARNING", logger="cryod.loop"):
        assert loop.run(duration_s=200.0, manage_gc=False) == 4
    assert any("bad_reply" in record.message and "recovering" in record.message for record in caplog.records)
    assert [event.kind for event in events] == ["fault", "stop"]
    assert "(exit 4)" in events[-1].text and "not recovered within 60 s" in events[-1].text
    assert 55 <= instruments.reconnects <= 62                       # about once a second
    assert rows[-1].time_s == pytest.approx(60.0, abs=1.0)
    assert all(row.heater_W == 0.0 for row in rows) and cryostat.heater_power_w == 0.0


def test_a_fault_from_the_first_reading_that_clears_closes_the_loop_from_0_W(reference_model, curves, base_config):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.measure_faults = {k: InstrumentTimeout("flange DMM", "no reply") for k in range(50)}
    assert loop.run(duration_s=900.0, manage_gc=False) == 0
    rows = tick_rows(rows)
    first_closed = next(i for i, row in enumerate(rows) if row.state.startswith("closed"))
    reconnect_ticks = [i for i, row in enumerate(rows[:first_closed]) if row.state == "recovering"
                       and math.isnan(row.T2_K)]
    assert reconnect_ticks == [1, 14, 27, 40, 53]        # once a second while failing, without a reading then
    assert first_closed == 55 + len(reconnect_ticks)
    assert [row.state for row in rows[first_closed - 5:first_closed]] == ["recovering"] * 5
    # closed from the 0 W it held, bumplessly: no integral wound up over the start-up faults
    assert rows[first_closed].control["pi_integral_W"] == pytest.approx(0.0, abs=1e-9)
    assert any(event.kind == "fault" and "instrument_timeout" in event.text for event in events)
    assert np.mean([row.T2_K for row in rows if row.time_s > 700.0]) == pytest.approx(5.0, abs=3e-4)


def test_a_dead_bus_says_the_heater_state_is_unknown_and_keeps_the_heater_fault(reference_model, curves,
                                                                                 base_config, caplog):
    """Every connection drops, the supply's too: it keeps its last current; the record must not claim 0 W."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    original = instruments.measure

    def measure():
        if instruments.measurements >= 1000:
            instruments.heater_off_error = ConnectionLost("heater supply", "socket closed")
            raise ConnectionLost("flange DMM", "socket closed")
        return original()

    instruments.measure = measure
    with caplog.at_level("WARNING", logger="cryod.loop"):
        assert loop.run(duration_s=200.0, manage_gc=False) == 6
    commanded = rows[999].heater_W
    assert commanded > 0.0 and cryostat.heater_power_w == commanded         # still on: nothing claims otherwise
    assert rows[-1].state == "fault:heater_fault" and np.isnan(rows[-1].heater_W)
    fault = loop.last_fault
    assert fault.cause == "heater_fault" and "UNKNOWN" in fault.message and "connection_lost" in fault.message
    assert f"{commanded:.4g} W" in fault.message
    assert events[-1].kind == "stop" and events[-1].text.endswith("(exit 6)")
    assert not any("recovering" in record.message for record in caplog.records)
    assert math.isnan(loop.status.heater_w) and "heater UNKNOWN" in loop.status.one_line()


def test_a_fault_that_keeps_coming_back_backs_off_and_ends_at_the_recovery_timeout(reference_model, curves,
                                                                                   base_config):
    """A supply that times out on every setting: resuming must not restart the timeout, and must back off."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    instruments.heater_faults = {k: InstrumentTimeout("heater supply", "no reply to the compliance query")
                                 for k in range(200, 100000)}
    assert loop.run(duration_s=600.0, manage_gc=False) == 4
    first_fault_time = next(row.time_s for row in rows if row.state.startswith("fault"))
    assert rows[-1].time_s - first_fault_time == pytest.approx(60.0, abs=1.5)
    resumes = [event for event in events if event.kind == "resumed" and "resume " in event.text]
    assert 3 <= len(resumes) <= 7                  # 0.4, 0.8, 1.6, 3.2, 6.4, 12.8 ... s of valid readings
    assert "(resumed" in loop.last_fault.message
    heater_on = sum(1 for row in rows if row.time_s > first_fault_time and row.heater_W > 0.0)
    assert heater_on == 0                           # every attempt failed before a power was confirmed
    assert cryostat.heater_power_w == 0.0


def test_feedforward_commands_fade_it_out_and_in_and_report(reference_model, curves, base_config):
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    answers = {}
    original = instruments.measure

    def measure():
        count = instruments.measurements
        if count in (2000, 2500, 2600):
            answers[count] = loop.submit(Command("feedforward", {2000: "off", 2500: "on", 2600: "status"}[count]))
        return original()

    instruments.measure = measure
    assert loop.run(duration_s=300.0, manage_gc=False) == 0
    scale = np.array([row.control.get("ff_scale", np.nan) for row in rows])
    assert scale[1990] == 1.0 and scale[2001 + 63] == 0.0 and 0.0 < scale[2030] < 1.0     # 5 s fade
    phase = np.array([row.control.get("ff_phase_rad", np.nan) for row in rows])
    assert scale[2499] == 0.0 and np.isnan(phase[2499])     # off: the cooler is not even tracked
    assert scale[2501 + int(15.0 / 0.08)] == 1.0            # on: locks again (about 6 s), then fades in
    assert answers[2000].ok and "fading out" in answers[2000].message
    status = answers[2600].message
    assert answers[2600].ok and "cooler phase locked" in status and "physical limit at 5 K" in status
    assert "what would change it: setpoint 4.5 K:" in status and "setpoint 5.5 K:" in status
    assert "µK" in status and " uK" not in status                  # one spelling of micro
    assert any(event.text.startswith("command: feedforward accepted") for event in events)


def test_the_feedforward_status_is_put_in_words_off_the_loops_thread(reference_model, curves, base_config,
                                                                      monkeypatch):
    """The loop's thread takes the snapshot; the words are put together on another thread, and the command is
    answered, journaled and recorded with them after the tick, as every command is."""
    import threading

    from cryod.control.feedforward import status_text as words_module

    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    threads = {}
    original_words, original_measure = words_module.status_text, instruments.measure

    def words(snapshot):
        threads["words"] = threading.current_thread()
        return original_words(snapshot)

    def measure():
        if instruments.measurements == 1000:
            threads["loop"] = threading.current_thread()
            threads["answer"] = loop.submit(Command("feedforward", "status"))
        return original_measure()

    monkeypatch.setattr(words_module, "status_text", words)
    instruments.measure = measure
    assert loop.run(duration_s=90.0, manage_gc=False) == 0
    answer = threads["answer"]
    assert threads["words"] is not threads["loop"] and answer.ok and "cooler phase locked" in answer.message
    recorded = [event for event in events if event.kind == "command"]
    assert [event.message for event in recorded] == [f"feedforward accepted: {answer.message}"]


def test_a_status_whose_words_are_late_is_refused_not_waited_for(reference_model, curves, base_config,
                                                                 monkeypatch):
    from cryod.control.feedforward import status_text as words_module
    from cryod.service import loop as loop_module

    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    release, answers, original_measure = threading.Event(), {}, instruments.measure

    def measure():
        if instruments.measurements == 500:
            answers["late"] = loop.submit(Command("feedforward", "status"))
        if instruments.measurements == 510:
            release.set()                               # the words' thread gets on after the refusal
        return original_measure()

    monkeypatch.setattr(words_module, "status_text", lambda snapshot: release.wait(60.0) and "never read")
    monkeypatch.setattr(loop_module, "WORDS_WAIT_S", 0.0)
    instruments.measure = measure
    assert loop.run(duration_s=60.0, manage_gc=False) == 0
    assert not answers["late"].ok and "its words were not ready" in answers["late"].message
    assert any(event.text.startswith("command: feedforward refused: feedforward not answered") for event in events)


def test_the_watchdog_is_fed_while_recovering(reference_model, curves, base_config):
    """systemd kills a daemon whose watchdog goes unfed for 10 s: a 30 s recovery is the loop doing its
    job (heater off, retrying), so every tick that returns feeds it; only a call that hangs starves it."""
    clock = VirtualClock()
    cryostat = SimulatedCryostat(reference_model, clock, seed=2)
    instruments = DirectInstruments(cryostat, *curves, clock)
    instruments.measure_faults = {k: InstrumentTimeout("flange DMM", "no reply") for k in range(500, 875)}
    fed = []
    loop = ControlLoop(base_config, instruments, *curves, clock, emit=lambda item: None,
                       watchdog=lambda: fed.append(clock.now()))
    assert loop.run(duration_s=120.0, manage_gc=False) == 0
    assert loop.last_fault.cause == "instrument_timeout"
    assert np.max(np.diff(fed)) < 0.2 and len(fed) == pytest.approx(120.0 / 0.08, abs=2)


def test_the_status_says_the_state_as_the_row_does(reference_model, curves, base_config):
    """On the way up from 4.2 K the heater is held at its top: the rows say closed-limited, and so does the status
    (ctl status, the web page, the 336 read it), not closed."""
    loop, instruments, cryostat, rows, events = make_loop(reference_model, curves, base_config)
    seen = []

    def measure():
        if instruments.measurements == 100:             # the status as of the tick before this one
            seen.append((loop.status.state, rows[-1].state))
        return DirectInstruments.measure(instruments)

    instruments.measure = measure
    assert loop.run(duration_s=10.0, manage_gc=False) == 0
    assert seen == [("closed-limited", "closed-limited")]
    assert tick_rows(rows)[99].heater_W == pytest.approx(0.5)


def test_a_setpoint_put_again_is_judged_once_and_said_each_time(reference_model, curves, base_config, monkeypatch,
                                                               caplog):
    """The heater's reach at a setpoint (the model's steady state, a third of a millisecond on the loop's thread) is
    worked out once while the setpoint, the control section and the heater's top stay; its warning is journaled at
    every put all the same, and another setpoint is judged anew."""
    import cryod.service.loop as loop_module

    loop, *_ = make_loop(reference_model, curves, base_config)
    judged = []
    real = loop_module.setpoint_warning
    monkeypatch.setattr(loop_module, "setpoint_warning",
                        lambda control, setpoint_K, top_W: judged.append(setpoint_K) or real(control, setpoint_K,
                                                                                           top_W))
    with caplog.at_level("WARNING", logger="cryod.loop"):
        warnings = [loop.warn_about_setpoint(setpoint) for setpoint in (16.0, 16.0, 16.0, 6.0, 16.0)]
    assert judged == [16.0, 6.0, 16.0]
    assert warnings[0] == warnings[1] == warnings[2] == warnings[4] and warnings[0].startswith("setpoint 16 K needs")
    assert warnings[3] is None and loop.setpoint_warning == warnings[4]
    assert sum("setpoint 16 K needs" in record.getMessage() for record in caplog.records) == 4
