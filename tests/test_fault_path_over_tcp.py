"""The fault path in real time over TCP: the heater really at 0 W within the loop's bound, and the record honest.

The daemon's drivers reach the simulated instruments through pyvisa-py on 127.0.0.1
(tests/fault_drills.py); the simulated supply logs the power it delivered, and that
log, not the daemon's word, says when the heater reached 0 W. The bound is
``InstrumentWaits.fault_to_off_s``: one loop period, the reading's own time and one
loop-path reply, then the heater-off. These runs take a few seconds of wall time
each; ALLOWANCE_S is room for a loaded test machine, far below what a wait of
``instruments.timeout_s`` would add. A run during which the machine kept the test's process from
running as long as the loop's wait for a reply is run again (``fault_drills.run_tcp_drill``): its
timing would say more about the machine than about the daemon.
"""

import math

import pytest

from cryod.instrument_waits import InstrumentWaits
from tests.fault_drills import never_claims_zero_early, reading_delay_s, run_tcp_drill

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system

#: Scheduling room on a loaded machine (s).
ALLOWANCE_S = 0.5
LARGEST_TIMEOUT_S = InstrumentWaits(0.08, 1.0).largest_timeout_s()


def assert_record_is_honest(drill, result):
    """The fault tick's row carries the power the supply had; the off's own row says 0 W from an instant at
    or after the supply's, and no row says 0 W while the supply still delivered power."""
    supply = drill.opener.bench.heater_supply
    assert result.fault_row.heater_W == pytest.approx(supply.power_at(result.fault_row.time_s), rel=1e-6)
    assert result.off_row.heater_W == 0.0 and result.off_row.state == result.fault_row.state
    assert result.real_off_s <= result.off_row.time_s <= result.real_off_s + drill.waits.loop_reply_s + ALLOWANCE_S
    assert result.off_row.heater_set_s == result.off_row.time_s
    assert never_claims_zero_early(result, supply.power_at) == []


def test_a_silent_dmm_with_the_longest_timeout_the_watchdog_allows(tmp_path):
    """The largest instruments.timeout_s (1.985 s): the heater is at 0 W within the loop's bound, not after two
    timeouts; a heater-off sent while the loop recovers and a stop after it are answered within a tick; the
    watchdog fed."""
    drill, result = run_tcp_drill(tmp_path, "silent flange DMM", timeout_s=LARGEST_TIMEOUT_S, fault_at_row=15,
                                  after_fault_s=6.0, heater_off_after_s=0.5, stop_after_s=1.5)
    waits = drill.waits
    assert result.exit_code == 0
    assert result.fault_to_off_s <= waits.fault_to_off_s(reading_delay_s(drill.daemon.loop)) + ALLOWANCE_S \
        < 2 * LARGEST_TIMEOUT_S
    assert result.fault_row.state == "fault:instrument_timeout"
    assert_record_is_honest(drill, result)
    assert result.heater_off_answer_s - result.heater_off_sent_s <= waits.longest_tick_s + ALLOWANCE_S
    assert result.stop_event_s - result.stop_requested_s <= waits.longest_tick_s + ALLOWANCE_S
    assert max(result.watchdog_gaps_s) <= waits.longest_tick_s + ALLOWANCE_S
    assert result.events[-1].kind == "stop" and "SIGTERM" in result.events[-1].text


def test_every_link_dropping_at_once_is_a_confirmed_off_and_a_recovery(tmp_path):
    """A Prologix controller all three instruments share resets: the off goes out again on a new connection
    and is confirmed there, so the loop recovers; the heater is not called UNKNOWN, nor the run a heater fault."""
    drill, result = run_tcp_drill(tmp_path, "every link drops at once", prologix=True, fault_at_row=15,
                                  after_fault_s=3.0)
    assert result.exit_code == 0
    assert result.fault_row.state == "fault:connection_lost"
    assert result.fault_to_off_s <= drill.waits.fault_to_off_s(reading_delay_s(drill.daemon.loop)) + ALLOWANCE_S
    assert_record_is_honest(drill, result)
    states = [str(row.state) for row in result.rows]
    assert "fault:heater_fault" not in states and states[-1].startswith("closed")
    assert not any("UNKNOWN" in event.text for event in result.events)
    assert any(event.kind == "resumed" and "after recovering" in event.text for event in result.events)


def test_a_silent_supply_ends_in_a_bounded_stop_tick_and_the_stop_is_the_last_word(tmp_path):
    """The supply executes but never answers: the off cannot be confirmed (exit 6, heater UNKNOWN, an empty
    heater_W from then on), the stop tick takes a setting and a heater-off, not several timeouts, and no
    overrun is written after the stop."""
    drill, result = run_tcp_drill(tmp_path, "silent heater supply", fault_at_row=15, after_fault_s=3.0)
    waits = drill.waits
    assert result.exit_code == 6
    assert result.fault_row.state == "fault:heater_fault" and result.fault_row.heater_W > 0.0
    assert result.off_row.state == "fault:heater_fault" and math.isnan(result.off_row.heater_W)
    assert result.stop_event_s - result.fault_s <= waits.fault_to_off_s(reading_delay_s(drill.daemon.loop)) + ALLOWANCE_S
    assert result.run_end_s - result.stop_event_s <= waits.heater_off_s + ALLOWANCE_S     # close's last try
    assert result.events[-1].kind == "stop" and "(exit 6)" in result.events[-1].text
    assert "UNKNOWN" in result.events[-1].text
    assert result.real_off_s is not None                  # the supply did execute the off it was sent
    assert result.fault_to_off_s <= waits.fault_to_off_s(reading_delay_s(drill.daemon.loop)) + ALLOWANCE_S
