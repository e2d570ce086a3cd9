"""Every fault through the real drivers and the simulated instruments' fault injection.

The whole daemon runs in process on virtual time: SimulatedInstrumentsOpener
builds the real drivers on the simulated bench, the Daemon runs its loop, and a
row tap injects a fault into the bench at a given tick. Each fault must put the
heater at 0 A in the tick that finds it, be recorded with its cause in the data
file and the status, and the daemon must then recover or exit with the fault's code.
"""

import dataclasses
import shutil

import numpy as np
import pytest

from drivers.clock import VirtualClock
from cryod.instrument_waits import InstrumentWaits
from cryod.service.daemon import Daemon
from cryod.records.record import read_record
from cryod.records.columns import Row
from cryod.service.instance_lock import InstanceLock
from cryod.service.notify import SystemdNotifier
from tests.example_config import simulated_config
from tests.fault_drills import FaultDrill, FlakyOpener, reading_delay_s


def first_fault(drill, cause):
    return drill.states.index(f"fault:{cause}")


@pytest.mark.parametrize("cause, inject, clear", [
    ("instrument_timeout", lambda bench: bench.flange_dmm.inject_no_reply(True),
     lambda bench: bench.flange_dmm.inject_no_reply(False)),
    ("sensor_overflow", lambda bench: bench.ptc_stage_dmm.inject_overflow(3), None),
    ("bad_reply", lambda bench: bench.flange_dmm.inject_garbage(2), None),
    ("connection_lost", lambda bench: bench.heater_supply.drop_connections(), None),
])
def test_transient_faults_heater_off_then_recover(tmp_path, cause, inject, clear):
    actions = {1500: inject}
    if clear is not None:
        actions[1503] = clear
    drill = FaultDrill(tmp_path, actions)
    assert drill.run(220.0).exit_code == 0
    index = first_fault(drill, cause)
    assert 1500 <= index <= 1502
    # the fault tick's row: the power the supply had; then the off's own row: 0 W from then on
    assert drill.record.heater_w[index] == drill.record.heater_w[index - 1] > 0.0
    assert not drill.ticks[index + 1] and drill.states[index + 1] == f"fault:{cause}"
    assert drill.record.heater_w[index + 1] == 0.0
    assert any(f"fault: {cause}" in text for _, text in drill.record.events)
    resumed = next(i for i in range(index, len(drill.states)) if drill.states[i].startswith("closed"))
    assert all(drill.record.heater_w[index + 1:resumed] == 0.0)
    assert resumed - index < 40                        # reconnected and 5 valid readings, within ~3 s
    late = drill.record.time_s > drill.record.time_s[-1] - 60
    assert np.mean(drill.record.flange_K[late]) == pytest.approx(5.0, abs=2e-3)
    assert drill.supply_current_a() == 0.0             # off at the end of the run


@pytest.mark.parametrize("timeout_s", [0.3, 1.0, 1.9])
def test_a_silent_dmm_has_the_supply_at_0_W_within_the_loops_bound_whatever_the_timeout(tmp_path, timeout_s):
    """The supply's own log: 0 W within one loop period, the reading's time, one loop-path reply and the
    heater-off after the DMM falls silent, not after instruments.timeout_s; the record's 0 W not before."""
    config = simulated_config(tmp_path)
    config = dataclasses.replace(config, instruments=dataclasses.replace(config.instruments, timeout_s=timeout_s))
    silent = {}

    def fall_silent(bench):
        silent["at"] = bench.clock.now()
        bench.flange_dmm.inject_no_reply(True)

    drill = FaultDrill(tmp_path, {300: fall_silent}, config=config)
    assert drill.run(40.0).exit_code == 0
    supply = drill.opener.bench.heater_supply
    off_s = supply.first_off_after(silent["at"])
    waits = InstrumentWaits(config.loop.period_s, timeout_s)
    assert off_s - silent["at"] <= waits.fault_to_off_s(reading_delay_s(drill.result.loop))
    index = first_fault(drill, "instrument_timeout")
    fault_row, off_row = drill.rows[index], drill.rows[index + 1]           # as emitted: clock times
    assert fault_row.heater_W == pytest.approx(supply.power_at(fault_row.time_s), rel=1e-6) and fault_row.heater_W > 0
    assert off_row.heater_W == 0.0 and off_s <= off_row.heater_set_s <= off_row.time_s


def test_heater_supply_refusing_output_stops_with_exit_6(tmp_path):
    drill = FaultDrill(tmp_path, {}, before_start=lambda bench: bench.heater_supply.inject_refuse_output())
    assert drill.run(60.0).exit_code == 6
    assert drill.result.loop.last_fault.cause == "heater_fault"
    assert "output" in drill.result.loop.last_fault.message
    assert drill.supply_current_a() == 0.0 and not drill.opener.bench.heater_supply.output_on


def test_an_output_that_goes_off_mid_run_is_seen_at_the_next_setting_and_stops_with_exit_6(tmp_path):
    """The supply's interlock opens at row 500 (output off, 0 A): the next setting reads the output state
    back, the loop stops on its own cause with the heater at 0 W, and the supply is left at 0 A and off, so
    that closing the interlock again brings no current back."""
    drill = FaultDrill(tmp_path, {500: lambda bench: bench.heater_supply.inject_refuse_output()})
    assert drill.run(120.0).exit_code == 6
    fault = drill.result.loop.last_fault
    assert fault.cause == "heater_output_off" and "interlock not asserted" in fault.message
    index = first_fault(drill, "heater_output_off")
    assert index <= 502 and drill.record.heater_w[index + 1] == 0.0 and len(drill.states) == index + 2
    supply = drill.opener.bench.heater_supply
    supply.inject_refuse_output(False)                 # the interlock closes again
    assert supply.current_setpoint_a == 0.0 and not supply.output_on and supply.output_current_a == 0.0
    assert any("(exit 6)" in text for _, text in drill.record.events)


def test_open_heater_compliance_stops_with_exit_6(tmp_path):
    drill = FaultDrill(tmp_path, {1000: lambda bench: bench.heater_supply.inject_open_heater()})
    assert drill.run(300.0).exit_code == 6
    assert drill.result.loop.last_fault.cause == "heater_fault"
    assert "compliance" in drill.result.loop.last_fault.message.lower()
    assert drill.states[-1] == "fault:heater_fault" and drill.record.heater_w[-1] == 0.0
    assert drill.supply_current_a() == 0.0


def test_over_temperature_stops_with_exit_3(tmp_path):
    config = simulated_config(tmp_path, setpoint_K=5.4, setpoint_max_K=5.5)
    config = dataclasses.replace(config, safety=dataclasses.replace(config.safety, flange_max_K=5.3))
    drill = FaultDrill(tmp_path, {}, config=config)
    assert drill.run(600.0).exit_code == 3
    assert drill.result.loop.last_fault.cause == "over_temperature"
    index = first_fault(drill, "over_temperature")
    assert drill.record.flange_K[index] > 5.3 and drill.record.heater_w[index] > 0.0
    assert drill.record.heater_w[index + 1] == 0.0 and drill.states[index + 1] == "fault:over_temperature"
    assert drill.supply_current_a() == 0.0


def test_recovery_timeout_exits_4(tmp_path):
    config = simulated_config(tmp_path)
    config = dataclasses.replace(config, safety=dataclasses.replace(config.safety, recovery_timeout_s=10.0))
    drill = FaultDrill(tmp_path, {500: lambda bench: bench.ptc_stage_dmm.inject_no_reply(True)}, config=config)
    assert drill.run(120.0).exit_code == 4
    assert "not recovered within 10 s" in drill.result.loop.last_fault.message
    assert drill.supply_current_a() == 0.0


def test_instruments_out_of_reach_at_start_are_waited_for_then_the_loop_runs(tmp_path, caplog):
    opener = FlakyOpener(failures=12)
    daemon = Daemon(simulated_config(tmp_path), opener, VirtualClock(), notifier=SystemdNotifier({}),
                    install_signal_handlers=False)
    with caplog.at_level("WARNING", logger="cryod.daemon"):
        result = daemon.run(120.0)
    assert result.exit_code == 0
    pauses = np.diff(opener.attempts)
    np.testing.assert_allclose(pauses[:7], [1, 2, 4, 8, 16, 32, 60], atol=0.01)   # backs off to once a minute
    assert sum(pauses) > 400.0                                                     # rode out a 7-minute outage
    record = read_record(result.log_paths[0])
    waiting = [text for _, text in record.events if text.startswith("event: waiting:")]
    assert len(waiting) == 12 and "no route to host" in waiting[0]
    assert sum("instruments out of reach" in r.message for r in caplog.records) == 12
    assert np.nanmean(record.flange_K[record.time_s > record.time_s[-1] - 20]) == pytest.approx(5.0, abs=0.05)


def test_waiting_for_instruments_is_bounded_when_configured(tmp_path):
    config = simulated_config(tmp_path)
    config = dataclasses.replace(config, safety=dataclasses.replace(config.safety, instruments_wait_s=300.0))
    opener = FlakyOpener(failures=10 ** 6)
    result = Daemon(config, opener, VirtualClock(), notifier=SystemdNotifier({}), install_signal_handlers=False).run(60.0)
    assert result.exit_code == 4 and result.loop is None
    assert 200.0 < opener.attempts[-1] - opener.attempts[0] <= 300.0


@pytest.mark.parametrize("wait_s", [5.0, 0.5, 61.0])
def test_the_wait_for_instruments_lasts_the_configured_time(tmp_path, wait_s):
    """The last attempt comes when the configured wait is up, not at the last doubling of the pause before it."""
    config = simulated_config(tmp_path)
    config = dataclasses.replace(config, safety=dataclasses.replace(config.safety, instruments_wait_s=wait_s))
    opener = FlakyOpener(failures=10 ** 6)
    result = Daemon(config, opener, VirtualClock(), notifier=SystemdNotifier({}), install_signal_handlers=False).run(60.0)
    assert result.exit_code == 4
    assert opener.attempts[-1] - opener.attempts[0] == pytest.approx(wait_s, abs=1e-9)
    assert all(later > earlier for earlier, later in zip(opener.attempts, opener.attempts[1:]))
    stop = [text for _, text in read_record(result.log_paths[0]).events if text.startswith("event: stop:")]
    assert stop == [f"event: stop: instruments out of reach for {wait_s:.1f} s (safety.instruments_wait_s {wait_s:g}): "
                    f"flange DMM (T2): cannot open TCPIP0::10.0.0.7::1234::SOCKET: no route to host (exit 4)"]


def test_a_second_daemon_touches_no_instrument(tmp_path):
    """Opening resets the instruments (heater off): a second daemon must stop before that."""
    config = simulated_config(tmp_path)
    first = InstanceLock(config.control_socket.path)
    first.acquire()
    try:
        opener = FlakyOpener(failures=0)
        result = Daemon(config, opener, VirtualClock(), notifier=SystemdNotifier({}),
                        install_signal_handlers=False).run(10.0)
    finally:
        first.release()
    assert result.exit_code == 2 and opener.attempts == [] and result.log_paths == []


# ---------------------------------------------------------------------------
# the data directory running out of space (docs/how-to/faults.md, "Disk space")
# ---------------------------------------------------------------------------
class FillingDisk:
    """Free space (bytes) of a disk that another program fills ``outside_per_byte`` times as fast as the
    data log writes its records: the free space falls with the rows, whatever the speed of the machine."""

    def __init__(self, start_bytes, outside_per_byte):
        self.start_bytes, self.outside_per_byte, self.checks = start_bytes, outside_per_byte, []

    def written(self, directory) -> int:
        return sum(path.stat().st_size for path in directory.glob("cryod-*.csv"))

    def __call__(self, directory):
        free = self.start_bytes - self.written(directory) * (1 + self.outside_per_byte)
        self.checks.append(free)
        return free


def test_a_filling_disk_warns_then_stops_the_heater_with_exit_7_while_the_record_still_fits(tmp_path):
    """Defaults: warn below 1000 MB, stop below 100 MB; the disk fills at about 5 MB per second of record."""
    disk = FillingDisk(1500e6, 2000)
    drill = FaultDrill(tmp_path, {}, datalog_options={"free_space": disk})
    result = drill.run(600.0)
    assert result.exit_code == 7 and result.loop.last_fault.cause == "data_log_failed"
    assert "below data.min_free_MB 100 MB" in result.loop.last_fault.message
    assert drill.supply_current_a() == 0.0 and drill.record.heater_w[-1] == 0.0
    events = [text for _, text in drill.record.events]
    warnings = [text for text in events if "below data.warn_free_MB" in text]
    assert len(warnings) == 1                                              # once, not at every check
    assert any("data_log_failed" in text and "(exit 7)" in text for text in events)    # the stop is recorded
    # checked at least once a second of the record (12.5 rows, 4.5 to 5.2 MB of filling), and at nearly every
    # row as the minimum comes near: the failure was found within two rows' filling (0.9 MB) of it
    falls = -np.diff(disk.checks[2:50])               # after the header (9 kB: 18 MB filled)
    assert len(disk.checks) > 250 and 0 < falls.max() < 6e6
    assert next(free for free in disk.checks if free < 100e6) > 99.1e6


def test_a_record_deleted_while_regulating_goes_on_in_a_new_file_to_the_stop(tmp_path, caplog):
    data = tmp_path / "data"
    drill = FaultDrill(tmp_path, {500: lambda bench: [path.unlink() for path in data.glob("cryod-*.csv")]})
    result = drill.run(100.0)
    assert result.exit_code == 0 and len(result.log_paths) == 2 and not result.log_paths[0].exists()
    first_event = drill.record.events[0][1]
    assert first_event.startswith(f"event: disk: the record's file {result.log_paths[0]} was deleted; it goes on "
                                  f"in this file")
    assert any("was deleted; it goes on in this file" in line.message for line in caplog.records)
    # from some rows before the deletion to the stop, every row, with the stop event
    assert np.allclose(np.diff(drill.record.time_s), 0.08) and len(drill.record) >= len(drill.rows) - 500
    assert drill.supply_current_a() == 0.0 and drill.record.events[-1][1].startswith("event: stop:")


def test_a_deleted_data_directory_stops_the_heater_with_exit_7(tmp_path):
    data = tmp_path / "data"

    def remove(bench):                   # as rm -rf, again if a new file got in meanwhile
        while data.exists():
            shutil.rmtree(data, ignore_errors=True)

    drill = FaultDrill(tmp_path, {500: remove})
    daemon_result = Daemon(drill.config, drill.open_instruments, VirtualClock(), notifier=SystemdNotifier({}),
                           row_taps=[drill.tap], install_signal_handlers=False).run(300.0)
    assert daemon_result.exit_code == 7 and daemon_result.loop.last_fault.cause == "data_log_failed"
    assert daemon_result.loop.last_fault.message == f"data.directory {data} is gone (deleted or moved)"
    assert drill.supply_current_a() == 0.0 and not data.exists()


def test_no_room_at_start_touches_no_instrument(tmp_path):
    opener = FlakyOpener(failures=0)
    daemon = Daemon(simulated_config(tmp_path), opener, VirtualClock(), notifier=SystemdNotifier({}),
                    install_signal_handlers=False, datalog_options={"free_space": lambda directory: 50e6})
    result = daemon.run(10.0)
    assert result.exit_code == 7 and opener.attempts == [] and result.loop is None


def test_a_data_directory_that_is_a_file_is_named_with_its_key(tmp_path, caplog):
    config = simulated_config(tmp_path)
    config.data.directory.parent.mkdir(parents=True, exist_ok=True)
    config.data.directory.write_text("not a directory")
    opener = FlakyOpener(failures=0)
    result = Daemon(config, opener, VirtualClock(), notifier=SystemdNotifier({}), install_signal_handlers=False).run(5.0)
    assert result.exit_code == 7 and opener.attempts == []
    assert any(f"data.directory {config.data.directory} is not a directory" in record.message
               for record in caplog.records)


# ---------------------------------------------------------------------------
# a DMM outage longer than a few seconds (each reply waits instruments.timeout_s)
# ---------------------------------------------------------------------------
class TimedOutage:
    """The flange DMM stops answering at row ``at_row`` for ``duration_s`` of clock time (None: for good)."""

    def __init__(self, drill, at_row, duration_s):
        self.drill, self.at_row, self.duration_s, self.started_s = drill, at_row, duration_s, None

    def __call__(self, item):
        if not isinstance(item, Row):
            return
        rows = self.drill.rows
        if len(rows) == self.at_row:
            self.started_s = item.time_s
            self.drill.opener.bench.flange_dmm.inject_no_reply(True)
        elif self.started_s is not None and self.duration_s is not None \
                and item.time_s - self.started_s >= self.duration_s:
            self.drill.opener.bench.flange_dmm.inject_no_reply(False)
            self.started_s = None


#: The 20 s outage is ``slow``: the 45 s one takes the same path and ends closer to the recovery timeout.
@pytest.mark.parametrize("outage_s", [pytest.param(20.0, marks=pytest.mark.slow), 45.0])
def test_a_dmm_outage_of_tens_of_seconds_is_recovered_not_an_overrun_streak(tmp_path, outage_s):
    drill = FaultDrill(tmp_path, {})
    outage = TimedOutage(drill, 1000, outage_s)
    original_tap = drill.tap
    drill.tap = lambda item: (original_tap(item), outage(item))
    assert drill.run(220.0).exit_code == 0
    assert drill.result.loop.last_fault.cause == "instrument_timeout"
    assert drill.states[-1].startswith("closed")
    assert not any("overrun" in text for _, text in drill.record.events)


def test_a_dmm_that_stays_dead_ends_in_exit_4_after_the_recovery_timeout(tmp_path):
    drill = FaultDrill(tmp_path, {})
    outage = TimedOutage(drill, 1000, None)
    original_tap = drill.tap
    drill.tap = lambda item: (original_tap(item), outage(item))
    assert drill.run(600.0).exit_code == 4
    fault = drill.result.loop.last_fault
    assert fault.cause == "instrument_timeout" and "not recovered within 60 s" in fault.message
    assert drill.supply_current_a() == 0.0
