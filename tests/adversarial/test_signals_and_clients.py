"""An adversarial run of the real ``cryod run`` at the process and service level (slow suite).

The daemon is ``cryod run`` in a child process, on the simulated instruments served over TCP
from this process; the supply logs what the heater really got and when. Tried:

- every signal that ends a process, one daemon each, the loop answering; SIGABRT and SIGTERM
  with the loop thread hung in an instrument call; SIGHUP (a reload, not a stop); SIGKILL and
  SIGSEGV (the supply keeps its last setting until the unit's ``cryod run --supply-off``);
- a thousand idle connections held open against the control socket (reopened as the daemon
  closes them), with ``heater-off`` sent meanwhile; garbage clients; eight hundred idle
  connections against the metrics endpoint;
- a second daemon on the first one's supply, and one sharing only a DMM.

Each category prints its figures (delay from the event to the supply at 0 W, overruns, the
daemon's threads); benchmarks/results/adversarial_signals.md ("Adversarial run") quotes them with this command::

    nice -n 10 .venv/bin/python -m pytest -m slow tests/adversarial/test_signals_and_clients.py -s
"""

import json
import os
import random
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
import urllib.request

import pytest

from cryod.service.control_socket import send_command
from cryod.service.stop_signals import exit_code_for, signal_name, terminating_signals
from tests.conftest import REPOSITORY
from tests.service_bench import BenchOverTcp, RunProcess, delay_to_zero_s

pytestmark = pytest.mark.slow

#: The bound every stop must keep: one loop period and one instrument call (instruments.timeout_s).
PERIOD_S, TIMEOUT_S = 0.08, 1.0


def threads_of(pid: int) -> int:
    with open(f"/proc/{pid}/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("Threads:"))


def figures(title: str, values: list[float], unit: str = "ms", scale: float = 1e3) -> str:
    scaled = sorted(value * scale for value in values)
    return (f"{title}: n={len(scaled)}, median {statistics.median(scaled):.1f} {unit}, "
            f"max {scaled[-1]:.1f} {unit}")


@pytest.fixture
def bench():
    with BenchOverTcp() as served:
        yield served


@pytest.fixture
def daemon(tmp_path, bench):
    started = []

    def start(name="daemon", hang_when=None, **sections):
        run = RunProcess(bench.write_config(tmp_path / name, **sections), hang_when=hang_when)
        started.append(run)
        return run

    yield start
    for run in started:
        run.close()


# ---------------------------------------------------------------------------
# signals
# ---------------------------------------------------------------------------
def test_every_terminating_signal_puts_the_supply_at_0_W_within_a_period_and_a_call(daemon, bench):
    delays, lines = [], []
    for number in terminating_signals():
        run = daemon(f"signal-{number}")
        run.wait_for_heating(bench.supply)
        time.sleep(0.3)
        sent = run.send(number)
        assert run.wait(30) == exit_code_for(number), run.journal[-2000:]
        delay = delay_to_zero_s(bench.supply, sent)
        assert delay is not None and delay < PERIOD_S + TIMEOUT_S, (signal_name(number), delay)
        name = signal_name(number)
        assert f"{name} received" in run.journal
        assert run.record().events[-1][1].startswith("event: stop: ") and f"{name} received" in \
            run.record().events[-1][1]
        delays.append(delay)
        lines.append(f"{name} {delay * 1e3:.0f} ms")
        run.close()
    print("\n" + figures(f"signals, loop answering ({len(delays)} signals)", delays))
    print("  " + ", ".join(lines))


@pytest.mark.parametrize("number", [signal.SIGABRT, signal.SIGTERM])
def test_a_signal_with_the_loop_hung_in_an_instrument_call(tmp_path, daemon, bench, number):
    """The reading watchdog has the heater off within safety.max_reading_age_s of the hang, before any signal;
    the signal then ends the process after the loop's grace, the heater held off."""
    hang = tmp_path / f"hang-{number}"
    run = daemon(f"hung-{number}", hang_when=hang)
    run.wait_for_heating(bench.supply)
    hung_at = time.monotonic()
    hang.touch()
    time.sleep(1.0)
    off_after_hang = delay_to_zero_s(bench.supply, hung_at)
    assert off_after_hang is not None and off_after_hang < 0.5 + 0.25
    run.wait_until(lambda: "heater switched off from the watchdog's thread" in run.journal,
                   "the watchdog's line in the journal (written by the log's own thread)", 10.0)
    sent = run.send(number)
    assert run.wait(30) == exit_code_for(number)
    assert delay_to_zero_s(bench.supply, sent) == 0.0            # off before the signal, and it stayed off
    print(f"\n{signal_name(number)}, loop hung in an instrument call: heater at 0 W {off_after_hang:.2f} s after "
          f"the hang (the reading watchdog), process ended {time.monotonic() - sent:.2f} s after the signal")


def test_sighup_reloads(daemon, bench):
    run = daemon("hup")
    run.wait_for_heating(bench.supply)
    run.send(signal.SIGHUP)
    time.sleep(1.0)
    assert run.process.poll() is None and run.status()["state"].startswith("closed")
    assert "reload" in run.journal


@pytest.mark.parametrize("number", [signal.SIGKILL, signal.SIGSEGV])
def test_what_cannot_be_caught_leaves_the_supply_to_the_units_supply_off(daemon, bench, number):
    """SIGKILL and a crash end the process at once with the supply at its last setting; the unit's ExecStopPost
    (cryod run --supply-off, run here as systemd runs it, the moment the process is gone) switches it off."""
    run = daemon(f"uncatchable-{number}")
    run.wait_for_heating(bench.supply)
    sent = run.send(number)
    assert run.wait(30) == -number
    ended_s = time.monotonic() - sent
    assert bench.supply.heater_power_w > 0.0                               # what the process left
    if number == signal.SIGSEGV:
        assert "Fatal Python error: Segmentation fault" in run.journal    # every thread's traceback
    done = subprocess.run([sys.executable, "-m", "cryod.cli", "run", "--config", str(run.config), "--supply-off"],
                          capture_output=True, text=True, timeout=60, env=dict(os.environ, PYTHONPATH=str(REPOSITORY)))
    assert done.returncode == 0, done.stderr
    delay = delay_to_zero_s(bench.supply, sent)
    assert delay is not None
    print(f"\n{signal_name(number)}: process gone {ended_s * 1e3:.0f} ms after the signal, supply at its last "
          f"setting until cryod run --supply-off put it at 0 W, {delay:.2f} s after the signal")


# ---------------------------------------------------------------------------
# clients
# ---------------------------------------------------------------------------
class IdleFlood:
    """``count`` connections to ``connect()`` that never send a byte, reopened as the daemon closes them."""

    def __init__(self, connect, count):
        self.connect, self.count = connect, count
        self.opened = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        import selectors

        selector = selectors.DefaultSelector()
        while not self._stop.is_set():
            while len(selector.get_map()) < self.count and not self._stop.is_set():
                try:
                    connection = self.connect()
                except OSError:
                    break
                connection.setblocking(False)
                selector.register(connection, selectors.EVENT_READ)
                self.opened += 1
            for key, _ in selector.select(timeout=0.05):
                selector.unregister(key.fileobj)                # closed (or answered) by the daemon: reopen
                key.fileobj.close()
        for key in list(selector.get_map().values()):
            key.fileobj.close()

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc_info):
        self._stop.set()
        self._thread.join(10)


def unix_connection(path):
    def connect():
        client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        client.settimeout(1.0)
        client.connect(str(path))
        return client
    return connect


def test_heater_off_gets_through_a_thousand_idle_connections(daemon, bench):
    run = daemon("idle-control")
    run.wait_for_heating(bench.supply)
    overruns_before = run.status()["overruns"]
    delays, threads = [], []
    with IdleFlood(unix_connection(run.socket_path), 1000) as flood:
        time.sleep(3.0)
        for _ in range(5):
            assert send_command(run.socket_path, "setpoint 5")["ok"]
            run.wait_for_heating(bench.supply)
            sent = time.monotonic()
            reply = send_command(run.socket_path, "heater-off")
            assert reply["ok"], reply
            delay = run.wait_until(lambda: delay_to_zero_s(bench.supply, sent), "0 W after heater-off", 10.0)
            delays.append(delay)
            threads.append(threads_of(run.process.pid))
        opened = flood.opened
    time.sleep(1.0)
    overruns = run.status()["overruns"] - overruns_before
    assert max(delays) < PERIOD_S + TIMEOUT_S + 0.5 and max(threads) < 40
    print(f"\n{figures('heater-off through 1000 idle control connections', delays)}; {opened} connections "
          f"opened by the flood; daemon threads at most {max(threads)}; overruns during the flood: {overruns}")


def test_garbage_clients_change_nothing_and_cost_no_overrun_streak(daemon, bench):
    run = daemon("garbage")
    run.wait_for_heating(bench.supply)
    overruns_before = run.status()["overruns"]
    rng = random.Random(25)
    payloads = [b"\xff\xfe" * 100 + b"\n", b"x" * 100_000, b"setpoint 55", b"\x00" * 64 + b"\n", b"status\r\n" * 50,
                b"heater-\n", b"setpoint nan\n", b"manual -1\n", b"setpoint 5\x00 heater-off\n", b"ramp 1_0\n"]
    replies, errors = [], []

    def client():
        for _ in range(20):
            try:
                connection = unix_connection(run.socket_path)()
                connection.sendall(rng.choice(payloads))
                if rng.random() < 0.5:
                    connection.shutdown(socket.SHUT_WR)
                replies.append(json.loads(connection.makefile("rb").readline() or b"{}"))
                connection.close()
            except (OSError, ValueError) as error:
                errors.append(error)

    clients = [threading.Thread(target=client) for _ in range(50)]
    for thread in clients:
        thread.start()
    for thread in clients:
        thread.join(60)
    time.sleep(0.5)
    status = run.status()
    assert status["state"].startswith("closed") and status["setpoint_K"] == 5.0 and run.process.poll() is None
    assert all(reply.get("ok") is False or reply.get("message") == "status" for reply in replies if reply)
    print(f"\ngarbage: {len(replies)} replies to 1000 hostile connections, {len(errors)} connections the daemon "
          f"closed first; still regulating; overruns meanwhile: {status['overruns'] - overruns_before}")


def test_eight_hundred_idle_metrics_connections_cost_no_thread_each(daemon, bench):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    run = daemon("metrics", metrics={"address": f"127.0.0.1:{port}"})
    run.wait_for_heating(bench.supply)
    time.sleep(1.0)
    threads_before = threads_of(run.process.pid)
    overruns_before = run.status()["overruns"]
    scrape_s = []
    with IdleFlood(lambda: socket.create_connection(("127.0.0.1", port), timeout=1.0), 800) as flood:
        time.sleep(3.0)
        threads_during = threads_of(run.process.pid)
        for _ in range(10):
            started = time.monotonic()
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as reply:
                assert reply.status == 200 and b"cryod_heater_power_watts" in reply.read()
            scrape_s.append(time.monotonic() - started)
        opened = flood.opened
    time.sleep(2.0)                                 # the flood closes: no burst of thread ends to pay for
    overruns = run.status()["overruns"] - overruns_before
    assert threads_during <= threads_before + 1
    print(f"\n800 idle metrics connections ({opened} opened): daemon threads {threads_before} before, "
          f"{threads_during} during; {figures('scrapes meanwhile', scrape_s)}; overruns: {overruns}")


# ---------------------------------------------------------------------------
# two daemons
# ---------------------------------------------------------------------------
def test_two_daemons_on_one_supply_or_one_dmm(daemon, bench):
    first = daemon("first")
    first.wait_for_heating(bench.supply)
    started = time.monotonic()
    second = daemon("second")
    assert second.wait(60) == 2
    assert "instruments.heater_supply.resource" in second.journal and "first/cryod.yaml" in second.journal
    refused_s = time.monotonic() - started
    only_dmm = daemon("only-dmm", instruments={"heater_supply": {"model": bench.supply_model,
                                                                  "resource": "TCPIP0::127.0.0.1::9::SOCKET"}})
    assert only_dmm.wait(60) == 2 and "instruments.flange_dmm.resource" in only_dmm.journal
    assert all(power > 0.0 for changed, power in bench.supply.delivered_w if changed >= started)
    assert first.process.poll() is None and first.status()["state"].startswith("closed")
    print(f"\nsecond daemon on the same instruments: exit 2 after {refused_s:.1f} s (its start-up), the first "
          f"daemon's supply never interrupted; a daemon sharing only the DMMs: exit 2")
