"""Every signal that would end the daemon, and an exception nobody caught in another thread: heater off, said, recorded.

In process, on virtual time: the daemon on the simulated bench runs in the test's main thread, and a
row tap sends a real signal to this process (or raises in a thread of its own). As a real process:
``cryod run`` against the simulated instruments over TCP, the supply in the test's process saying
what the heater really got and when; once with a loop that answers, once with a loop thread hung in
an instrument call, which only the last resort of the stop brings to 0 W.
"""

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from cryod.service.daemon import Daemon, stop_grace_s
from cryod.service.stop_signals import CRASH_SIGNALS, exit_code_for, terminating_signals
from cryod.config import load_config
from tests.conftest import REPOSITORY
from tests.service_bench import BenchOverTcp, RunProcess, delay_to_zero_s, faults_of_its_own
from tests.fault_drills import FaultDrill

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system

#: Each kind: systemd's watchdog, the user signals, the terminal's quit, a timer, power failure, a real-time
#: signal, and the two usual stops.
SIGNALS = [signal.SIGABRT, signal.SIGUSR1, signal.SIGUSR2, signal.SIGQUIT, signal.SIGALRM, signal.SIGPWR,
           signal.SIGRTMIN + 3, signal.SIGTERM, signal.SIGINT]


def test_the_signals_caught_are_every_one_that_would_end_the_process_but_the_uncatchable_and_the_crashes(
        terminal_signals):
    caught = set(terminating_signals())
    assert set(SIGNALS) <= caught and set(range(signal.SIGRTMIN, signal.SIGRTMAX + 1)) <= caught
    assert not caught & {signal.SIGKILL, signal.SIGSTOP, signal.SIGHUP, *CRASH_SIGNALS}
    assert signal.SIGPIPE not in caught                   # ignored (Python): a write to a closed pipe fails instead
    assert not caught & {signal.SIGCHLD, signal.SIGWINCH, signal.SIGURG, signal.SIGCONT, signal.SIGTSTP}
    assert [exit_code_for(number) for number in (signal.SIGTERM, signal.SIGINT, signal.SIGABRT, signal.SIGUSR1)] \
        == [0, 0, 134, 138]


@pytest.mark.parametrize("number", SIGNALS, ids=[signal.Signals(n).name if n in signal.Signals._value2member_map_
                                                 else f"SIGRTMIN+{n - signal.SIGRTMIN}" for n in SIGNALS])
def test_each_signal_stops_the_daemon_with_the_heater_at_0_W_and_says_why(tmp_path, number, caplog):
    missed = []                 # a signal the daemon did not take ends up here, not in the end of the test run
    previous = signal.signal(number, lambda *arguments: missed.append(number))
    try:
        before = {n: signal.getsignal(n) for n in (number, signal.SIGHUP)}
        drill = FaultDrill(tmp_path, {300: lambda bench: signal.raise_signal(number)})
        drill.install_signal_handlers = True
        with caplog.at_level("INFO", logger="cryod"):
            result = drill.run(120.0)
        after = {n: signal.getsignal(n) for n in before}
    finally:
        signal.signal(number, previous)
    assert missed == [] and after == before                                     # handlers given back
    assert result.exit_code == exit_code_for(number)
    assert drill.supply_current_a() == 0.0 and not drill.opener.bench.heater_supply.output_on
    heater = drill.record.heater_w
    assert heater[299] > 0.0 and len(heater) <= 301                             # stopped at the next tick
    stops = [text for row, text in drill.record.events if text.startswith("event: stop:") and row == len(heater)]
    name = signal.Signals(number).name if number in signal.Signals._value2member_map_ else "SIGRTMIN+3"
    cause = "stop_requested" if number in (signal.SIGTERM, signal.SIGINT) else "signal"
    assert len(stops) == 1 and stops[0].startswith(f"event: stop: {cause}: {name} received")
    assert stops[0].endswith(f"(exit {exit_code_for(number)})")
    journal = [record.getMessage() for record in caplog.records]
    assert any(line.startswith(f"{name} received") and "stopping with the heater at 0 W" in line for line in journal)


def test_an_exception_nobody_caught_in_another_thread_stops_the_daemon_with_the_heater_off(tmp_path, caplog):
    def fail_in_a_thread(bench):
        worker = threading.Thread(target=lambda: 1 / 0, name="a helper")
        worker.start()
        worker.join()

    hook_before = threading.excepthook
    drill = FaultDrill(tmp_path, {300: fail_in_a_thread})
    drill.install_signal_handlers = True
    with caplog.at_level("INFO", logger="cryod"):
        result = drill.run(120.0)
    assert result.exit_code == 1 and drill.supply_current_a() == 0.0
    stops = [text for row, text in drill.record.events
             if text.startswith("event: stop:") and row == len(drill.record.heater_w)]
    assert stops == ["event: stop: exception: unhandled ZeroDivisionError in thread a helper: division by zero "
                     "(exit 1)"]
    assert any(record.getMessage() == "unhandled exception in thread a helper" and record.exc_info
               for record in caplog.records)                                  # the traceback, in the journal
    assert threading.excepthook is hook_before                                  # given back


def test_an_exception_outside_the_loop_is_recorded_with_the_heater_off(tmp_path):
    """An error after the instruments are open and before the loop runs: the record still says why."""
    drill = FaultDrill(tmp_path, {})

    def broken_start(*arguments, **options):
        raise RuntimeError("no real-time session")

    import cryod.service.daemon as daemon_module
    original = daemon_module.RealtimeSession
    daemon_module.RealtimeSession = broken_start
    try:
        with pytest.raises(RuntimeError):
            drill.run(10.0)
    finally:
        daemon_module.RealtimeSession = original
    assert drill.supply_current_a() == 0.0
    events = [text for _, text in drill.daemon_record().events]
    assert events[-1] == "event: stop: exception: RuntimeError: no real-time session (exit 1)"


# ---------------------------------------------------------------------------
# cryod run as a real process
# ---------------------------------------------------------------------------
@pytest.fixture
def bench():
    with BenchOverTcp() as served:
        yield served


def test_sigabrt_from_the_watchdog_puts_the_supply_at_0_W_within_a_period_and_says_why(tmp_path, bench):
    run = RunProcess(bench.write_config(tmp_path / "daemon"))
    try:
        run.wait_for_heating(bench.supply)
        sent = run.send(signal.SIGABRT)
        assert run.wait(30) == 134
        delay = delay_to_zero_s(bench.supply, sent)
        assert delay is not None and delay < 0.08 + 1.0                 # a period and one instrument call at most
        assert not bench.supply.output_on
        journal = run.journal
        assert "cryod.daemon: critical: SIGABRT received (systemd's watchdog sends it when the loop stops feeding it): " \
               "stopping with the heater at 0 W (exit 134)" in journal
        assert "cryod/service/loop.py" in journal                      # where the loop was, for a hang
        record = run.record()
        row, text = record.events[-1]
        assert row == len(record.heater_w)                              # after the last row
        assert text.startswith("event: stop: signal: SIGABRT received") and text.endswith("(exit 134)")
    finally:
        run.close()


def test_a_loop_hung_in_an_instrument_call_is_stepped_over_the_heater_goes_off_and_the_process_ends(tmp_path, bench):
    """The loop thread waits forever inside a reading (no timeout ends it): the reading watchdog switches the
    heater off once its setting is safety.max_reading_age_s (0.5 s) older than its readings, and says so; a
    signal then finds the loop stuck, the signal's thread holds the heater off after the loop's grace and ends
    the process after as long again."""
    config = bench.write_config(tmp_path / "daemon", instruments={"timeout_s": 0.3})
    grace_s = stop_grace_s(load_config(config))
    hang = tmp_path / "hang"
    run = RunProcess(config, hang_when=hang)
    try:
        run.wait_for_heating(bench.supply)
        hung_at = time.monotonic()
        hang.touch()
        time.sleep(0.25)
        assert bench.supply.heater_power_w > 0.0                        # hung with the heater on ...
        deadline = time.monotonic() + 5.0
        while bench.supply.heater_power_w > 0.0 and time.monotonic() < deadline:
            time.sleep(0.01)
        delay = delay_to_zero_s(bench.supply, hung_at)
        # ... until its setting is 0.5 s older than its readings (triggered up to a period and a reading
        # before the hang), a look of the watchdog (20 ms) and the supply's off later
        assert delay is not None and 0.5 - 0.08 - 0.05 <= delay < 0.5 + 0.25
        run.wait_until(lambda: "heater switched off from the watchdog's thread" in run.journal,
                       "the watchdog's line in the journal (written by the log's own thread)", 10.0)
        sent = run.send(signal.SIGUSR1)
        assert run.wait(30) == 138
        stepped_in = f"SIGUSR1 received; the loop did not stop within {grace_s:.3g} s: heater switched off from " \
                     f"outside the loop"
        assert f"cryod.daemon: critical: {stepped_in}" in run.journal
        assert bench.supply.zero_since(sent) is not None and not bench.supply.output_on
        events = [text for _, text in run.record().events]
        assert any(text.startswith("event: watchdog: readings_too_old: the heater's setting came from readings")
                   for text in events)
        assert events[-2:] == [
            f"event: stopping: {stepped_in}",
            "event: stop: signal: SIGUSR1 received; the loop thread was stuck, the process was ended from outside "
            "it with the heater off (exit 138)"]
    finally:
        run.close()


def supply_off(config) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cryod.cli", "run", "--config", str(config), "--supply-off"],
                          capture_output=True, text=True, timeout=60, env=dict(os.environ, PYTHONPATH=str(REPOSITORY),
                                                                              SERVICE_RESULT="signal",
                                                                              EXIT_STATUS="KILL"))


def supply_off_beside_a_daemon_then_after_its_sigkill(folder, bench):
    """``--supply-off`` while ``cryod run`` drives the supply, then after a SIGKILL: both results, the power the
    supply delivered after each, when the kill was sent, and the faults the daemon found by itself before it."""
    config = bench.write_config(folder)
    run = RunProcess(config)
    try:
        run.wait_for_heating(bench.supply)
        refused = supply_off(config)
        alone = (bench.supply.heater_power_w, run.process.poll() is None)
        killed_at = run.send(signal.SIGKILL)
        run.wait(10)
        left_w = bench.supply.heater_power_w
        own_faults = faults_of_its_own(run.journal)
        done = supply_off(config)
        return refused, alone, killed_at, left_w, own_faults, done
    finally:
        run.close()


def test_after_sigkill_the_units_supply_off_switches_the_supply_off_and_leaves_a_running_daemons_alone(tmp_path,
                                                                                                      bench):
    """What the unit's ExecStopPost runs: the supply a SIGKILL left at its last setting goes to 0 A, output
    off; while a daemon drives it, the same command leaves it alone. A run in which the daemon switched its
    heater off for a fault of its own (a reply late on a busy machine) shows neither, and is run again."""
    faults = []
    for attempt in range(3):
        refused, (alone_w, running), killed_at, left_w, own_faults, done = \
            supply_off_beside_a_daemon_then_after_its_sigkill(tmp_path / f"daemon{attempt}", bench)
        if not own_faults:
            break
        faults.append(own_faults[0])
    else:
        raise AssertionError(f"the daemon switched its heater off by itself in every run: {faults}")
    assert refused.returncode == 2 and "supply left alone (the daemon ended: SERVICE_RESULT signal, " \
                                       "EXIT_STATUS KILL)" in refused.stderr
    assert alone_w > 0.0 and running
    assert left_w > 0.0                                             # what SIGKILL leaves
    assert done.returncode == 0, done.stderr
    assert "heater supply at 0 A, output off (the daemon ended: SERVICE_RESULT signal" in done.stderr
    assert bench.supply.heater_power_w == 0.0 and not bench.supply.output_on
    assert delay_to_zero_s(bench.supply, killed_at) < 30.0
