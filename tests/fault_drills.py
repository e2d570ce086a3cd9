"""Fault drills: the daemon on the simulated instruments, a fault injected, on virtual time or over TCP.

:class:`FaultDrill` runs the whole daemon in process on the virtual clock against the simulated
bench, and a row tap fires actions (faults injected into the bench) after given rows;
:class:`FlakyOpener` keeps the instruments out of reach for a number of attempts to open them.

:class:`TcpFaultDrill` runs the whole daemon in process on the monotonic clock, its
real drivers reaching the simulated bench through pyvisa-py over TCP on 127.0.0.1
(each instrument on its own port, or all three behind one simulated Prologix
controller). Once the heater is on, a row tap injects a fault into the bench and
notes the clock instant; the simulated supply's own log of the power it delivered
then says when the heater really reached 0 W, which the drill holds against the
daemon's record (its rows, as the loop emitted them, with their clock times).

Shared by the default suite's fault tests and the slow adversarial run.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from cryod.config import load_config
from cryod.instrument_waits import InstrumentWaits
from cryod.model import load_model
from cryod.records.columns import Event, Row
from cryod.records.record import read_record
from drivers.clock import MonotonicClock, VirtualClock
from cryod.service.commands import Command, wait_for
from cryod.service.daemon import Daemon
from cryod.service.notify import SystemdNotifier
from cryod.service.simulation import SimulatedInstrumentsOpener
from drivers.errors import ConnectionLost
from tests.conftest import CONFIG
from tests.example_config import simulated_config
from tests.stall_probe import StallProbe


def reading_delay_s(loop) -> float:
    """The longest time from a trigger to both readings of the loop's DMMs (s)."""
    instruments = loop.instruments
    return getattr(instruments, "instruments", instruments).pair.reading_delay_s      # behind the heater guard


class WatchdogRecorder(SystemdNotifier):
    """A notifier without systemd that notes when the daemon fed the watchdog (clock times)."""

    def __init__(self, clock):
        super().__init__(environ={})
        self.clock = clock
        self.fed: list[float] = []

    def watchdog(self) -> None:
        self.fed.append(self.clock.now())


#: Faults a drill injects, by name: ``inject(bench)``.
FAULTS: dict[str, Callable] = {
    "silent flange DMM": lambda bench: bench.flange_dmm.inject_no_reply(True),
    "silent PTC-stage DMM": lambda bench: bench.ptc_stage_dmm.inject_no_reply(True),
    "garbage from the flange DMM": lambda bench: bench.flange_dmm.inject_garbage(10 ** 6),
    "silent heater supply": lambda bench: bench.heater_supply.inject_no_reply(True),
    "garbage from the heater supply": lambda bench: bench.heater_supply.inject_garbage(10 ** 6),
    "every link drops at once": lambda bench: bench.drop_every_connection(),
}


@dataclass
class DrillResult:
    """What a drill measured (clock times in s; None: did not happen)."""

    exit_code: int
    fault_s: float
    real_off_s: float | None              # the supply's log: first instant at 0 W after the fault
    recorded_off_s: float | None          # the record: time of the first row after the fault saying 0 W
    fault_row: Row | None                 # the row of the tick that found the fault
    off_row: Row | None                   # the heater-off's own row
    rows: list[Row]
    events: list[Event]
    watchdog_gaps_s: list[float]
    heater_off_sent_s: float | None       # a heater-off command sent after the fault
    heater_off_answer_s: float | None     # and when the loop answered it
    stop_event_s: float | None            # clock time the stop event was emitted
    stop_requested_s: float | None
    run_end_s: float
    supply_log: list[tuple[float, float]] = field(default_factory=list)
    largest_stall_s: float = 0.0          # the longest the machine kept this process from running during the run

    @property
    def fault_to_off_s(self) -> float | None:
        return None if self.real_off_s is None else self.real_off_s - self.fault_s


class DrillNotStarted(AssertionError):
    """The run ended before the fault was injected; ``largest_stall_s``: how long the machine stalled it."""

    def __init__(self, message: str, largest_stall_s: float):
        super().__init__(f"{message} (the process was stalled for up to {largest_stall_s:.2f} s)")
        self.largest_stall_s = largest_stall_s


class TcpFaultDrill:
    """Runs the daemon over TCP in real time and injects ``fault`` once the heater has been on a while.

    Parameters
    ----------
    tmp_path : pathlib.Path
    fault : str
        A key of :data:`FAULTS`.
    timeout_s : float
        ``instruments.timeout_s``.
    prologix : bool
        All three instruments behind one simulated Prologix GPIB-ETHERNET controller.
    fault_at_row : int
        The fault is injected after this row (the heater regulating by then).
    after_fault_s : float
        How long the run goes on after the fault (clock seconds).
    heater_off_after_s : float, optional
        Send ``heater-off`` through the loop's command queue (as the control socket does) this long after the fault.
    stop_after_s : float, optional
        Ask for a stop (as SIGTERM does) this long after the fault.
    """

    def __init__(self, tmp_path, fault: str, *, timeout_s: float = 1.0, prologix: bool = False,
                 fault_at_row: int = 30, after_fault_s: float = 3.0, heater_off_after_s: float | None = None,
                 stop_after_s: float | None = None):
        config = load_config(CONFIG / "cryod.yaml")
        instruments = dataclasses.replace(config.instruments, timeout_s=timeout_s,
                                          trigger="prologix" if prologix else config.instruments.trigger)
        self.config = dataclasses.replace(
            config,
            instruments=instruments,
            loop=dataclasses.replace(config.loop, realtime_priority=0, lock_memory=False,
                                     overrun_streak_limit=1000),   # a loaded test machine is not the fault
            data=dataclasses.replace(config.data, directory=tmp_path / "data"),
            control_socket=dataclasses.replace(config.control_socket, path=tmp_path / "control.sock"),
            simulation=dataclasses.replace(config.simulation, transport="tcp"))
        self.waits = InstrumentWaits(self.config.loop.period_s, timeout_s)
        self.inject = FAULTS[fault]
        self.fault_at_row = fault_at_row
        self.after_fault_s = after_fault_s
        self.heater_off_after_s = heater_off_after_s
        self.stop_after_s = stop_after_s
        self.clock = MonotonicClock()
        self.opener = SimulatedInstrumentsOpener(load_model(), seed=4)
        self.notifier = WatchdogRecorder(self.clock)
        self.rows: list[Row] = []
        self.events: list[Event] = []
        self.fault_s: float | None = None
        self.heater_off_sent_s: float | None = None
        self.heater_off_answer_s: float | None = None
        self.stop_requested_s: float | None = None
        self.stop_event_s: float | None = None
        self._helpers: list[threading.Thread] = []
        self.daemon: Daemon | None = None

    # -- the loop's rows ------------------------------------------------------------
    def tap(self, item) -> None:
        if isinstance(item, Event):
            self.events.append(item)
            if item.kind == "stop" and self.stop_event_s is None:
                self.stop_event_s = self.clock.now()
            return
        self.rows.append(item)
        if len(self.rows) == self.fault_at_row and self.fault_s is None:
            if not item.heater_W > 0.0:
                raise AssertionError(f"the heater is not on at row {self.fault_at_row}: {item}")
            self.fault_s = self.clock.now()
            self.inject(self.opener.bench)
            if self.heater_off_after_s is not None:
                self._helper(self._send_heater_off)
            if self.stop_after_s is not None:
                self._helper(self._stop_later)

    def _helper(self, target) -> None:
        thread = threading.Thread(target=target, daemon=True)
        self._helpers.append(thread)
        thread.start()

    def _send_heater_off(self) -> None:
        time.sleep(self.heater_off_after_s)
        self.heater_off_sent_s = self.clock.now()
        command = wait_for(self.daemon.loop.submit(Command("heater-off", sender="drill")), 30.0)
        if command.ok:
            self.heater_off_answer_s = self.clock.now()

    def _stop_later(self) -> None:
        time.sleep(self.stop_after_s)
        self.stop_requested_s = self.clock.now()
        self.daemon.loop.request_stop("SIGTERM received")

    # -- the run --------------------------------------------------------------------------
    def run(self) -> DrillResult:
        self.daemon = Daemon(self.config, self.opener, self.clock, notifier=self.notifier, row_taps=[self.tap],
                             install_signal_handlers=False)
        duration = self.fault_at_row * self.config.loop.period_s + 2.0 + self.after_fault_s
        with StallProbe() as probe:
            result = self.daemon.run(duration)
        run_end = self.clock.now()
        for thread in self._helpers:
            thread.join(30.0)
        if self.fault_s is None:
            raise DrillNotStarted(f"the fault was never injected: {len(self.rows)} rows", probe.largest_s)
        supply = self.opener.bench.heater_supply
        after = [row for row in self.rows if row.time_s >= self.fault_s - self.config.loop.period_s]
        fault_row = next((row for row in after if str(row.state).startswith("fault:")), None)
        off_row = next((row for row in after if math.isnan(row.lateness_ms)), None)
        recorded_off = next((row.time_s for row in self.rows if row.time_s > self.fault_s and row.heater_W == 0.0),
                            None)
        fed = [t for t in self.notifier.fed if t >= self.fault_s]
        gaps = [b - a for a, b in zip(fed, fed[1:])]
        return DrillResult(result.exit_code, self.fault_s, supply.first_off_after(self.fault_s), recorded_off,
                           fault_row, off_row, list(self.rows), list(self.events), gaps, self.heater_off_sent_s,
                           self.heater_off_answer_s,
                           self.stop_event_s, self.stop_requested_s, run_end, list(supply.delivered_w),
                           probe.largest_s)


def run_tcp_drill(tmp_path, fault: str, *, attempts: int = 3, **options) -> tuple[TcpFaultDrill, DrillResult]:
    """A :class:`TcpFaultDrill` (``fault``, ``options``) run while the machine let this process run.

    The drill judges real-time bounds of a few hundred milliseconds; a run during which the machine kept
    this process from running as long as the loop's own wait for a reply (:class:`tests.stall_probe.StallProbe`)
    cannot tell a late reply from a silent instrument, so it is run again in a fresh folder, up to
    ``attempts`` times. What the drill found is not looked at here: a run the machine let run is the
    run the test judges, whatever it shows.
    """
    stalls = []
    for attempt in range(attempts):
        folder = tmp_path / f"run{attempt}"
        folder.mkdir()
        drill = TcpFaultDrill(folder, fault, **options)
        try:
            result = drill.run()
        except DrillNotStarted as not_started:
            if not_started.largest_stall_s < drill.waits.loop_reply_s:
                raise
            stalls.append(f"{not_started.largest_stall_s:.2f} s")
            continue
        if result.largest_stall_s < drill.waits.loop_reply_s:
            return drill, result
        stalls.append(f"{result.largest_stall_s:.2f} s")
    raise AssertionError(f"the machine kept this process from running for {', '.join(stalls)} in {attempts} runs "
                         f"of the drill, as long as the loop's wait for a reply: no run to judge")


def never_claims_zero_early(result: DrillResult, supply_power_at: Callable[[float], float]) -> list[str]:
    """Rows after the fault that say 0 W at an instant the supply still delivered power (the problems found)."""
    problems = []
    for row in result.rows:
        if row.time_s >= result.fault_s and row.heater_W == 0.0 and supply_power_at(row.time_s) > 0.0:
            problems.append(f"row at {row.time_s:.6f} s ({row.state}) says 0 W; the supply delivered "
                            f"{supply_power_at(row.time_s):.4g} W then")
    return problems


class FaultDrill:
    """Runs the daemon on the simulated bench; ``actions[tick](bench)`` fires after that row."""

    def __init__(self, tmp_path, actions, config=None, before_start=None, datalog_options=None):
        self.config = config or simulated_config(tmp_path)
        self.datalog_options = datalog_options
        self.opener = SimulatedInstrumentsOpener(load_model(), seed=4)
        self.actions = dict(actions)
        self.before_start = before_start
        self.rows = []
        self.heater_at_fault = []
        self.install_signal_handlers = False        # the daemon's own signal handling (the test's main thread)

    def tap(self, item):
        if not isinstance(item, Row):
            return
        self.rows.append(item)
        action = self.actions.pop(len(self.rows) - 1, None)
        if action is not None:
            action(self.opener.bench)

    def open_instruments(self, config, clock):
        opened = self.opener(config, clock)
        if self.before_start is not None:
            self.before_start(self.opener.bench)
        return opened

    def run(self, duration_s):
        self.daemon = Daemon(self.config, self.open_instruments, VirtualClock(), notifier=SystemdNotifier({}),
                             row_taps=[self.tap], install_signal_handlers=self.install_signal_handlers,
                             datalog_options=self.datalog_options)
        self.result = self.daemon.run(duration_s)
        self.record = self.daemon_record()
        self.states = [str(state) for state in self.record.columns["state"]]
        #: The rows that stand for a tick (a heater-off's own row has no lateness).
        self.ticks = np.isfinite(self.record.columns["lateness_ms"])
        return self.result

    def daemon_record(self):
        """The record the daemon wrote last (also after its run raised)."""
        return read_record(self.daemon.datalog.paths[-1])

    def supply_current_a(self):
        return self.opener.bench.heater_supply.output_current_a


class FlakyOpener:
    """Instruments out of reach for the first ``failures`` attempts (the bus is down), then the bench."""

    def __init__(self, failures):
        self.inner = SimulatedInstrumentsOpener(load_model(), seed=4)
        self.failures = failures
        self.attempts = []

    def __call__(self, config, clock):
        self.attempts.append(clock.now())
        if len(self.attempts) <= self.failures:
            raise ConnectionLost("flange DMM (T2)", "cannot open TCPIP0::10.0.0.7::1234::SOCKET: no route to host")
        return self.inner(config, clock)
