"""Data log, control socket, systemd notify and journald logging."""

import json
import logging
import os
import socket
import subprocess
import sys
import time

import pytest

from cryod.records.columns import REQUIRED, STATE, Column, Event, Row, RowSchema
from cryod.service.states import LoopState
from cryod.records.datalog import DataLog
from cryod.records.record import read_record
from cryod.service.commands import Command, parse_command
from cryod.service.control_socket import ControlSocketServer, send_command
from cryod.service.logs import JournalFormatter
from cryod.service.notify import SystemdNotifier
from tests.conftest import CONFIG
from tests.record_rows import SCHEMA, rows


def test_data_log_writes_contract_files_and_never_overwrites(tmp_path):
    wall_start = 1_795_000_000.0       # 2026-11-18 UTC, mid-day
    log_a = DataLog(tmp_path, SCHEMA, {"site": "test"}, lambda t: wall_start + t, 0.08, 0.5)
    log_a.start()
    log_a.put(Event("note", "started"))
    log_a.put(Event("fault", "exception: RuntimeError: first line\nsecond line"))   # before the first file opens
    for row in rows(0.08, 100):
        log_a.put(row)
    log_a.stop()
    log_b = DataLog(tmp_path, SCHEMA, {}, lambda t: wall_start + t, 0.08, 0.5)   # restart the same day
    log_b.start()
    for row in rows(50.0, 10):
        log_b.put(row)
    log_b.stop()
    first, second = log_a.paths[0], log_b.paths[0]
    assert first.name == "cryod-2026-11-18.csv" and second.name == "cryod-2026-11-18.2.csv"
    record = read_record(first)
    assert len(record) == 100 and record.time_s[0] == pytest.approx(0.08)
    assert record.metadata["site"] == "test" and "record_start_utc" in record.metadata
    assert first.read_text().splitlines()[0] == "# cryod-log v1"
    assert read_record(second).time_s[0] == pytest.approx(0.08)     # each file counts from its own start
    assert any("started" in line for line in first.read_text().splitlines()[:5])
    assert record.events[1] == (0, "event: fault: exception: RuntimeError: first line second line")


def test_data_log_rotates_at_utc_midnight(tmp_path):
    midnight = 1_795_046_400.0         # 2026-11-19 00:00:00 UTC
    datalog = DataLog(tmp_path, SCHEMA, {}, lambda t: midnight - 4.0 + t, 0.08, 0.5)
    datalog.start()
    for row in rows(0.08, 100):        # 8 s across midnight
        datalog.put(row)
    datalog.stop()
    names = [path.name for path in datalog.paths]
    assert names == ["cryod-2026-11-18.csv", "cryod-2026-11-19.csv"]
    before, after = (read_record(path) for path in datalog.paths)
    assert len(before) + len(after) == 100
    assert after.time_s[0] == pytest.approx(0.08)


def test_parse_command_refuses_malformed_input():
    assert parse_command("setpoint 5.0").value == 5.0
    for line, reason in [("", "empty"), ("warm", "unknown command"), ("setpoint", "takes 1 argument"),
                         ("setpoint five", "not a number"), ("ramp nan", "not a number"), ("ramp 1e999", "finite"),
                         ("setpoint 1_5", "plain decimal"), ("setpoint \u0665", "not a number"),
                         ("heater-off now", "takes 0"), ("reload now", "takes 0"), ("modulate 1 2 3", "unknown command")]:
        with pytest.raises(ValueError, match=reason):
            parse_command(line)


def test_control_socket_round_trip_and_permissions(tmp_path):
    path = tmp_path / "control.sock"
    seen = []

    def submit(command: Command) -> Command:
        seen.append((command.name, command.value))
        command.answer(command.value is None or command.value < 10, "done" if (command.value or 0) < 10 else "refused: too hot")
        return command

    server = ControlSocketServer(path, 0o660, None, None, submit, lambda: {"T2_K": 5.0, "state": "closed"})
    server.start()
    try:
        assert (os.stat(path).st_mode & 0o777) == 0o660
        reply = send_command(path, "status")
        assert reply["ok"] and reply["status"]["T2_K"] == 5.0
        assert send_command(path, "setpoint 5.5")["ok"]
        refused = send_command(path, "setpoint 50")
        assert not refused["ok"] and "too hot" in refused["message"]
        malformed = send_command(path, "setpoint hot")
        assert not malformed["ok"] and "not a number" in malformed["message"]
        assert seen == [("setpoint", 5.5), ("setpoint", 50.0)]     # malformed never reached the loop
        with pytest.raises(OSError, match="in use"):
            ControlSocketServer(path, 0o660, None, None, submit, dict).start()
    finally:
        server.stop()
    assert not path.exists()
    with pytest.raises(ConnectionError, match="no cryod daemon"):
        send_command(path, "status")


def test_control_socket_never_replaces_a_regular_file(tmp_path):
    path = tmp_path / "control.sock"
    path.write_text("precious")
    with pytest.raises(OSError, match="not a socket"):
        ControlSocketServer(path, 0o660, None, None, lambda c: c, dict).start()
    assert path.read_text() == "precious"


def test_systemd_notify_datagrams_on_a_real_socket(tmp_path):
    address = str(tmp_path / "notify")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(address)
    listener.settimeout(2.0)
    try:
        notifier = SystemdNotifier({"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "2000000"})
        notifier.ready("started")
        assert listener.recv(4096).decode().split("\n") == ["READY=1", "STATUS=started"]
        notifier.watchdog()
        notifier.watchdog()            # rate-limited: only one ping within 0.5 s
        assert listener.recv(4096) == b"WATCHDOG=1"
        notifier.status("T2 5.0 K")
        assert listener.recv(4096) == b"STATUS=T2 5.0 K"
        notifier.reloading()
        assert listener.recv(4096).startswith(b"RELOADING=1\nMONOTONIC_USEC=")
    finally:
        listener.close()


def test_notify_abstract_socket_and_absent_socket():
    name = f"cryod-test-{os.getpid()}"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind("\0" + name)
    listener.settimeout(2.0)
    try:
        SystemdNotifier({"NOTIFY_SOCKET": "@" + name}).stopping("bye")
        assert listener.recv(4096) == b"STOPPING=1\nSTATUS=bye"
    finally:
        listener.close()
    quiet = SystemdNotifier({})
    quiet.ready("x")                   # nothing to send to: no error
    assert not quiet.enabled and quiet.watchdog_interval_s is None


def test_journald_priority_prefixes():
    formatter = JournalFormatter(prefix=True)
    record = logging.LogRecord("cryod.service.loop", logging.CRITICAL, __file__, 1, "heater off: %s", ("over_temperature",), None)
    assert formatter.format(record) == "<2>cryod.service.loop: heater off: over_temperature"
    record = logging.LogRecord("cryod", logging.WARNING, __file__, 1, "two\nlines", (), None)
    assert formatter.format(record) == "<4>cryod: two\n<4>lines"
    assert JournalFormatter(prefix=False).format(record) == "cryod: warning: two\nlines"
    record = logging.LogRecord("cryod.loop", logging.INFO, __file__, 1, "setpoint 5 K", (), None)
    assert JournalFormatter(prefix=False).format(record) == "cryod.loop: setpoint 5 K"


def test_priority_prefixes_only_for_the_journal_whatever_stderr_is(monkeypatch):
    from cryod.service.logs import wants_prefix

    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    assert not wants_prefix()                           # a pipe, a file, a terminal: levels in words
    monkeypatch.setenv("JOURNAL_STREAM", "8:12345")      # systemd's service with StandardError=journal
    assert wants_prefix()


def test_notify_never_blocks_on_a_receiver_that_does_not_read(tmp_path):
    address = str(tmp_path / "notify")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(address)
    try:
        notifier = SystemdNotifier({"NOTIFY_SOCKET": address})
        started = time.monotonic()
        for _ in range(5000):
            notifier.status("x" * 200)
        assert time.monotonic() - started < 2.0
        assert notifier.dropped > 0
    finally:
        listener.close()


def test_memory_lock_pins_what_is_used_not_everything_mapped():
    """mlockall of every mapped page made numpy's and scipy's libraries resident (hundreds of MB)."""
    script = ("import numpy, scipy.signal\n"
              "from cryod.service.realtime import lock_memory\n"
              "def resident():\n"
              "    return next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmRSS'))\n"
              "before = resident()\n"
              "problem, figure = lock_memory()\n"
              "print(before, resident(), problem is None, figure)\n")
    output = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout.split()
    before_kb, after_kb, locked = int(output[0]), int(output[1]), output[2] == "True"
    if not locked:
        pytest.skip("memory locking not permitted here")
    assert after_kb < 1.2 * before_kb + 10_000
    assert "MB resident" in " ".join(output[3:])


def test_the_writers_fast_path_writes_what_each_column_formats():
    schema = RowSchema(REQUIRED + (STATE,) + (Column("T2_sample_s", "s", "", "{:.5f}", is_time=True),
                                            Column("extra", "", "")))
    row = Row(time_s=10.08, lateness_ms=0.0, state=LoopState.CLOSED, T2_K=4.2306589, T5_K=float("nan"),
              heater_W=0.0, T2_sample_s=10.09, control={"extra": 0.30000000000000004})
    expected = ",".join(column.formatted(value) for column, value in zip(
        schema.columns, (0.08, 4.2306589, None, 0.0, None, "closed", 0.09, 0.30000000000000004))) + "\n"
    assert schema.format_row(row, origin_s=10.0) == expected == \
        "0.0800,4.2306589,,0.000000e+00,,closed,0.09000,0.30000000000000004\n"


REALTIME_RUN = '''
import dataclasses, json, os, sys, threading
from cryod.config import load_config
from cryod.model import load_model
from cryod.records.columns import Row
from drivers.clock import VirtualClock
from cryod.service.daemon import Daemon
from cryod.service.notify import SystemdNotifier
from cryod.service.simulation import SimulatedInstrumentsOpener

config = load_config(sys.argv[1])
config = dataclasses.replace(
    config, loop=dataclasses.replace(config.loop, realtime_priority=20, lock_memory=True),
    data=dataclasses.replace(config.data, directory=sys.argv[2] + "/data"),
    control_socket=dataclasses.replace(config.control_socket, path=sys.argv[2] + "/control.sock"),
    simulation=dataclasses.replace(config.simulation, transport="in-process"))
policies = {}

def tap(item):
    if isinstance(item, Row):
        names = {thread.native_id: thread.name for thread in threading.enumerate()}
        for task in os.listdir("/proc/self/task"):
            try:
                policies[names.get(int(task), "other")] = os.sched_getscheduler(int(task))
            except OSError:
                pass

def locked_kB():
    return next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmLck"))

before = os.sched_getscheduler(0)
daemon = Daemon(config, SimulatedInstrumentsOpener(load_model(), seed=4), VirtualClock(),
                notifier=SystemdNotifier({}), row_taps=[tap], install_signal_handlers=False)
result = daemon.run(30.0)
print(json.dumps({"exit": int(result.exit_code), "before": before, "after": os.sched_getscheduler(0),
                  "policies": policies, "locked_kB": locked_kB()}))
'''


@pytest.mark.system
def test_a_real_time_run_keeps_its_workers_at_normal_priority_and_gives_everything_back(tmp_path):
    """Threads the loop thread starts inherit its SCHED_FIFO: the feedforward's limit ran at the loop's
    priority, and the process stayed SCHED_FIFO with its memory locked after the run (tests, cryod.simulate)."""
    try:
        probe = subprocess.run([sys.executable, "-c", "import os; os.sched_setscheduler(0, os.SCHED_FIFO, "
                                "os.sched_param(1))"], capture_output=True)
    except OSError:
        pytest.skip("no real-time scheduling here")
    if probe.returncode != 0:
        pytest.skip("real-time priority not permitted here")
    output = subprocess.run([sys.executable, "-c", REALTIME_RUN, str(CONFIG / "cryod.yaml"), str(tmp_path)],
                            capture_output=True, text=True, timeout=120)
    assert output.returncode == 0, output.stderr[-2000:]
    run = json.loads(output.stdout.splitlines()[-1])
    assert run["exit"] == 0
    assert run["policies"]["MainThread"] == os.SCHED_FIFO            # the loop thread
    workers = {name: policy for name, policy in run["policies"].items() if name.startswith("cryod-feedforward")}
    assert "cryod-feedforward-limit_0" in workers                    # the limit was computed during the run
    assert set(workers.values()) == {os.SCHED_OTHER}, workers
    assert run["after"] == run["before"] == os.SCHED_OTHER
    assert run["locked_kB"] == 0
