"""The daemon as a real process: systemd notify, control socket, SIGHUP reload, SIGTERM, SIGKILL.

These run ``cryod --simulate`` in real time with the drivers talking to the
simulated instruments through pyvisa-py over TCP, so they take a few seconds
of wall time each.
"""

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from cryod.records.record import read_record
from cryod.service.control_socket import send_command
from tests.conftest import CONFIG, REPOSITORY

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system


def write_config(path: Path, proportional=10.0) -> Path:
    text = (CONFIG / "cryod.yaml").read_text()
    text = text.replace("calibration: calibration/", f"calibration: {CONFIG / 'calibration'}/")
    text = text.replace("proportional_W_per_K: 10.0", f"proportional_W_per_K: {proportional}")
    path.write_text(text)
    return path


class DaemonProcess:
    def __init__(self, tmp_path: Path, *arguments: str, notify=True):
        self.tmp_path = tmp_path
        self.config = write_config(tmp_path / "cryod.yaml")
        self.socket_path = tmp_path / "control.sock"
        self.data = tmp_path / "data"
        env = dict(os.environ, PYTHONPATH=str(REPOSITORY))
        self.notify = None
        self.messages: list[str] = []
        if notify:                    # read continuously, as systemd does
            self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            self.notify.bind(str(tmp_path / "notify"))
            self.notify.settimeout(0.2)
            # as systemd starts a service whose standard error is the journal
            env.update(NOTIFY_SOCKET=str(tmp_path / "notify"), WATCHDOG_USEC="2000000", JOURNAL_STREAM="8:12345")
            self._reading = True
            self._reader = threading.Thread(target=self._read_notifications, daemon=True)
            self._reader.start()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "cryod.cli", "--simulate", "--config", str(self.config), "--data-dir",
             str(self.data), "--socket", str(self.socket_path), *arguments],
            env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def _read_notifications(self) -> None:
        while self._reading:
            try:
                self.messages.append(self.notify.recv(4096).decode())
            except socket.timeout:
                pass
            except OSError:
                return

    def receive(self, seconds: float) -> None:
        time.sleep(seconds)

    def wait_for_message(self, prefix: str, seconds: float = 30.0) -> str:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for message in list(self.messages):
                if message.startswith(prefix) or f"\n{prefix}" in message:
                    return message
            if self.process.poll() is not None:
                break
            self.receive(0.2)
        raise AssertionError(f"no {prefix!r} from the daemon; got {self.messages[-5:]}; "
                             f"stderr: {self.process.stderr.read() if self.process.poll() is not None else ''}")

    def wait_for_rows(self, minimum: int, seconds: float = 30.0) -> Path:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            files = sorted(self.data.glob("cryod-*.csv"))
            if files and sum(1 for line in files[0].read_text().splitlines() if line[:1].isdigit()) >= minimum:
                return files[0]
            time.sleep(0.1)
        raise AssertionError("no data rows")

    def close(self):
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(10)
        if self.notify is not None:
            self._reading = False
            self._reader.join(2.0)
            self.notify.close()


@pytest.fixture
def daemon(tmp_path):
    processes = []

    def start(*arguments, **options):
        process = DaemonProcess(tmp_path, *arguments, **options)
        processes.append(process)
        return process

    yield start
    for process in processes:
        process.close()


def test_service_behaviour_of_a_real_process(daemon):
    run = daemon("--duration", "120")
    ready = run.wait_for_message("READY=1")
    assert "STATUS=started" in ready
    run.wait_for_message("WATCHDOG=1")                    # fed from the loop after good cycles
    run.wait_for_rows(10)
    status = send_command(run.socket_path, "status")
    assert status["ok"] and status["status"]["state"] in ("holding", "closed", "closed-limited")
    refused = send_command(run.socket_path, "setpoint 50")
    assert not refused["ok"] and "outside 3..20 K" in refused["message"]
    assert send_command(run.socket_path, "ramp 2")["ok"]
    run.wait_for_message("STATUS=closed")                 # about once a second

    write_config(run.config, proportional=12.0)           # a good change, then a bad one
    run.process.send_signal(signal.SIGHUP)
    run.wait_for_message("RELOADING=1")
    run.wait_for_message("STATUS=configuration reloaded from")     # READY=1 with the reload's outcome
    run.config.write_text(run.config.read_text().replace("proportional_W_per_K: 12.0", "proportional_W_per_K: hot"))
    run.process.send_signal(signal.SIGHUP)
    run.wait_for_message("STATUS=reload refused")
    assert send_command(run.socket_path, "status")["ok"]  # still running on the good configuration

    run.process.send_signal(signal.SIGTERM)
    assert run.process.wait(15) == 0
    run.receive(0.5)
    assert any(message.startswith("STOPPING=1") for message in run.messages)
    assert any(message.startswith("RELOADING=1") for message in run.messages)
    stderr = run.process.stderr.read()
    lines = [line for line in stderr.splitlines() if line]
    assert lines and all(line[0] == "<" and line[2] == ">" for line in lines), stderr[:500]
    assert "reload refused, keeping the running configuration" in stderr and "proportional_W_per_K" in stderr
    record = read_record(sorted(run.data.glob("cryod-*.csv"))[0])
    events = " | ".join(text for _, text in record.events)
    assert "command: reload accepted: configuration reloaded" in events
    assert "command: setpoint refused: setpoint 50 K refused" in events
    assert "stop: stop_requested: SIGTERM received" in events
    assert record.heater_w[-1] == 0.0 or record.columns["state"][-1] != "closed"
    assert record.metadata["simulation_transport"] == "tcp"
    assert "proportional_W_per_K: 10.0" in record.metadata["config"]


def test_sigkill_loses_at_most_two_seconds_and_the_file_parses(daemon):
    run = daemon("--duration", "600", notify=True)
    run.wait_for_message("READY=1")
    ready_at = time.monotonic()
    path = run.wait_for_rows(40)
    time.sleep(2.5)
    killed_at = time.monotonic()
    run.process.kill()
    run.process.wait(10)
    record = read_record(path)
    expected_last = killed_at - ready_at                  # the loop starts right after READY
    assert len(record) > 40 and not [w for w in record.warnings if "cut short" not in w]
    assert record.time_s[-1] >= expected_last - 2.0, (record.time_s[-1], expected_last)


def _file_size_limit(limit_bytes):
    """In the child: files may not grow beyond ``limit_bytes`` (a full disk, as the writer meets it)."""
    import resource

    def apply():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)       # the write then fails with EFBIG instead of a kill
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return apply


def test_a_write_that_fails_stops_the_heater_with_exit_7_and_keeps_what_was_written(tmp_path):
    """No room left: the data file cannot grow past 400 kB. The write fails in the writer thread, the loop
    switches the heater off and the daemon exits 7 (not 0); the file holds every row written before."""
    env = dict(os.environ, PYTHONPATH=str(REPOSITORY))
    result = subprocess.run(
        [sys.executable, "-m", "cryod.cli", "--simulate", "--config", str(write_config(tmp_path / "cryod.yaml")),
         "--data-dir", str(tmp_path / "data"), "--socket", str(tmp_path / "control.sock"), "--speed", "max",
         "--duration", "3600"],
        env=env, capture_output=True, text=True, timeout=120, preexec_fn=_file_size_limit(400_000), cwd=tmp_path)
    assert result.returncode == 7, result.stderr[-2000:]
    assert "data_log_failed" in result.stderr and "File too large" in result.stderr
    assert "heater off, stopping (exit 7)" in result.stderr
    (path,) = (tmp_path / "data").glob("cryod-*.csv")
    record = read_record(path)                          # parses; a cut-short last line is dropped
    assert path.stat().st_size <= 400_000 and len(record.time_s) > 500
