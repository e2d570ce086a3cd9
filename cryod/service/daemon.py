"""The daemon: configuration, instruments, loop, data log, control socket, systemd, signals.

``cryod run`` and ``cryod --simulate`` both come here; they differ only in
the instruments handed over (real ones, locked against other daemons, or drivers
talking to simulated ones) and the clock.

Threads: the main thread runs the control loop and nothing else. The data
log writer, the control socket (with the live stream), the status/reload
service thread, the log listener and the reading watchdog run beside it and
talk to the loop through queues and snapshots. The web page, the Lake Shore 336
command set, the metrics and the alarm hooks run in a second process, the
interfaces process, which the daemon starts and starts again when it ends
(:mod:`cryod.service.interfaces_process`). The signal watch sees every
terminating signal at once; when the loop does not stop within
:func:`stop_grace_s` of one (or of an exception in another thread), a thread of
the daemon switches the heater off through the :class:`HeaterGuard` and, if the
loop thread stays stuck, ends the process.
"""

from __future__ import annotations

import collections
import faulthandler
import logging
import math
import os
import platform
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from cryod import __version__
from cryod.config import DaemonConfig, load_config, located_error
from cryod.control.setpoint_reach import controller_model
from cryod.instrument_waits import InstrumentWaits
from cryod.records.datalog import DataLog
from cryod.records.columns import Event, RowSchema
from cryod.service.alarms import AlarmMonitor
from cryod.service.commands import Command, wait_for
from cryod.service.daemon_status import DaemonStatus, status_json
from cryod.service.faults import ExitCode, Fault, FaultCause
from cryod.service.heater_guard import HeaterGuard
from cryod.service.instance_lock import AlreadyRunning, InstanceLock, InstrumentLocks
from cryod.service.interfaces_process import InterfacesProcess, interface_settings
from cryod.service.lakeshore336 import Lakeshore336Setup
from cryod.service.live_view import LiveView
from cryod.service.stream import StreamHub, StreamTap
from cryod.service.loop import ControlLoop, Instruments, daemon_schema
from cryod.service.reading_watchdog import ReadingWatchdog
from cryod.service.realtime import RealtimeSession
from cryod.service.control_socket import ControlSocketServer
from cryod.service.notes import write_note
from cryod.service.notify import SystemdNotifier
from cryod.service.stop_signals import (REQUESTED_STOP_SIGNALS, SignalWatch, exit_code_for,
                                        install_thread_exception_hook, signal_received)
from cryod.yaml_source import FileFormatError
from drivers.clock import Clock
from drivers.errors import IdentityMismatch, InstrumentError

log = logging.getLogger("cryod.daemon")

#: Longest pause between two attempts to open instruments that do not answer (s).
MAX_RETRY_PAUSE_S = 60.0


class _NotStarted(Exception):
    """The daemon stops before touching an instrument (said in the journal and the record already)."""


@dataclass
class RunResult:
    """What a daemon run ended with."""

    exit_code: int
    loop: ControlLoop | None
    log_paths: list[Path]           # every record written, where each is now (a finished day's as .csv.gz)
    wall_s: float


def record_metadata(config: DaemonConfig, schema: RowSchema, extra: dict | None = None) -> dict:
    """Header lines of every data file: versions, units, heater, configuration snapshot."""
    metadata = {
        "cryod_version": __version__,
        "python_version": platform.python_version(),
        "numpy_version": np.__version__,
        "host": socket.gethostname(),
        "units": schema.units_text(),
        "loop_period_s": config.loop.period_s,
        "heater_resistance_ohm": config.heater.resistance_ohm,
        "heater_max_current_A": config.heater.max_current_A,
        "heater_max_power_W": config.heater.max_power_w,
        "flange_calibration": config.sensors.flange_calibration,
        "ptc_stage_calibration": config.sensors.ptc_stage_calibration,
        "config_file": config.source,
    }
    metadata.update(extra or {})
    metadata["config"] = config.text
    return metadata


class Daemon:
    """Assembles and runs the daemon.

    Parameters
    ----------
    config : DaemonConfig
    open_instruments : callable
        ``open_instruments(config, clock) -> (instruments, flange_curve, ptc_stage_curve)``;
        raises on failure (nothing is left on).
    clock : Clock
    notifier : SystemdNotifier, optional
    metadata : dict, optional
        Extra header lines for the data files (e.g. the simulated model).
    row_taps : list of callable, optional
        Also receive every row and event (e.g. the --simulate metrics).
    install_signal_handlers : bool
        Every signal that would end the process stops the daemon with the heater off, SIGHUP reloads,
        and an exception nobody caught in another thread stops it too (main thread only;
        :mod:`cryod.service.stop_signals`).
    reload_config : callable, optional
        Reads and validates the configuration again on reload (default:
        :func:`cryod.config.load_config` of the file it came from);
        ``cryod --simulate`` passes one that applies its command-line overrides.
    datalog_options : dict, optional
        More keyword arguments of :class:`~cryod.records.datalog.DataLog` (tests: a fake disk's
        ``free_space``).
    instrument_addresses : callable, optional
        ``instrument_addresses(config) -> {canonical address: [keys]}`` of the real instruments, locked
        host-wide for the whole run before any is touched (``cryod run``:
        :func:`cryod.service.instruments.instrument_addresses`); a simulation's instruments are its own.
    interfaces_options : dict, optional
        More keyword arguments of :class:`~cryod.service.interfaces_process.InterfacesProcess` (tests: where
        it logs).
    """

    def __init__(self, config: DaemonConfig, open_instruments: Callable, clock: Clock,
                 notifier: SystemdNotifier | None = None, metadata: dict | None = None,
                 row_taps: list[Callable] | None = None, install_signal_handlers: bool = True,
                 reload_config: Callable[[], DaemonConfig] | None = None, datalog_options: dict | None = None,
                 instrument_addresses: Callable[[DaemonConfig], dict[str, list[str]]] | None = None,
                 interfaces_options: dict | None = None):
        self.config = config
        self.reload_config = reload_config or (lambda: load_config(self.config.source))
        self.open_instruments = open_instruments
        self.clock = clock
        self.notifier = notifier or SystemdNotifier()
        self.metadata = metadata or {}
        self.row_taps = row_taps or []
        self.datalog_options = datalog_options or {}      # e.g. a fake disk's free space, for tests
        self.install_signal_handlers = install_signal_handlers
        self.instrument_addresses = instrument_addresses
        self.interfaces_options = interfaces_options or {}     # e.g. where the interfaces process logs, for tests
        self.loop: ControlLoop | None = None
        self.datalog: DataLog | None = None
        #: The wall clock (s since the epoch, as the record's timestamps) at the daemon's clock time 0: a clock
        #: time plus this is the time of day the record gives it.
        self.clock_offset_s = 0.0
        #: Why the run did not start because another daemon runs this cryostat (None otherwise).
        self.not_started: str | None = None
        #: The latest row and faults, for the status line and ``cryod ctl status``'s figures of the recent past.
        self.live_view = LiveView(config.loop.period_s, cooler_rad_s(config))
        #: The alarms (``alarms``): the last row tap; their hook runs in the interfaces process.
        self.alarms = AlarmMonitor(config.alarms, config.heater.max_power_w, cooler_rad_s(config),
                                   config.loop.period_s)
        self.live_view.attach_alarms(self.alarms.raised_names)
        #: The live stream of the control socket (``subscribe``): a row tap, and its side on the socket's thread.
        self.stream_tap = StreamTap()
        self.stream = StreamHub(self.stream_tap, self._stream_status, self._hello)
        self._lakeshore_setup: tuple[object, Lakeshore336Setup | None] = (None, None)
        #: The interfaces process (web page, 336 command set, metrics, alarm hooks), when any is configured.
        self.interfaces: InterfacesProcess | None = None
        self._reload_wanted = False
        self._socket_reloads: collections.deque[Command] = collections.deque()   # "reload" from the socket
        self._stop_reason: str | None = None
        self._stop_as: tuple[int, FaultCause] = (ExitCode.OK, FaultCause.STOP_REQUESTED)
        self._waiting = "opening the instruments"
        self._service_stop = False
        self._service_wake = threading.Event()      # a reload or the stop
        self._guard: HeaterGuard | None = None      # the loop's instruments, once open
        self._loop_done = threading.Event()         # the loop has stopped (the heater off), or never ran
        self._outside_stop: threading.Thread | None = None
        self._outside_stop_lock = threading.Lock()

    # -- stops from outside the loop: signals, exceptions in other threads ---------------
    def _request_stop(self, reason: str, exit_code: int = ExitCode.OK,
                      cause: FaultCause = FaultCause.STOP_REQUESTED) -> None:
        """Ask for the stop (flags only: safe in a signal handler); the first reason is kept."""
        if self._stop_reason is None:
            self._stop_as = (exit_code, cause)
            self._stop_reason = reason
        loop = self.loop
        if loop is not None:
            loop.request_stop(reason, exit_code, cause)

    def _on_stop_signal(self, number: int) -> None:
        """Main thread, as the signal handler."""
        self._request_stop(signal_received(number), exit_code_for(number),
                           FaultCause.STOP_REQUESTED if number in REQUESTED_STOP_SIGNALS else FaultCause.SIGNAL)

    def _on_signal_seen(self, number: int) -> None:
        """The signal-watching thread, as soon as a terminating signal arrives."""
        reason = signal_received(number)
        if self._outside_stop is not None:
            log.warning("%s while stopping", reason)
            return
        requested = number in REQUESTED_STOP_SIGNALS
        log.log(logging.INFO if requested else logging.CRITICAL, "%s: stopping with the heater at 0 W (exit %d)",
                reason, exit_code_for(number))
        if not requested:                   # where every thread was: for a watchdog's SIGABRT, what hung
            faulthandler.dump_traceback(all_threads=True)
        self._stop_from_outside(reason, exit_code_for(number),
                                FaultCause.STOP_REQUESTED if requested else FaultCause.SIGNAL)

    def _on_thread_exception(self, thread_name: str, error: BaseException) -> None:
        self._stop_from_outside(f"unhandled {type(error).__name__} in thread {thread_name}: {error}",
                                ExitCode.EXCEPTION, FaultCause.EXCEPTION)

    def _stop_from_outside(self, reason: str, exit_code: int, cause: FaultCause) -> None:
        """Ask the loop to stop, and see it through from a thread of its own (:meth:`_see_the_stop_through`)."""
        self._request_stop(reason, exit_code, cause)
        with self._outside_stop_lock:
            if self._outside_stop is not None:
                return
            self._outside_stop = threading.Thread(target=self._see_the_stop_through, args=(reason, exit_code, cause),
                                                  name="cryod-stop", daemon=True)
            self._outside_stop.start()

    def _see_the_stop_through(self, reason: str, exit_code: int, cause: FaultCause) -> None:
        """The loop stops by itself within :func:`stop_grace_s`; when it does not (it is stuck in an instrument
        call or a bug), the heater is switched off from here and held off, and said; when the loop thread is
        still stuck after as long again, the process is ended from here, its record and journal written."""
        grace_s = stop_grace_s(self.config)
        if self._loop_done.wait(grace_s):
            return
        guard = self._guard
        if guard is None:               # the instruments are not open: the heater was never set
            return
        problem = guard.hold_off(reason, wait_s=self.config.instruments.timeout_s)
        message = (f"{reason}; the loop did not stop within {grace_s:.3g} s: "
                   + ("heater switched off from outside the loop" if problem is None else problem))
        log.critical("%s", message)
        self.datalog.put(Event("stopping", message))
        if self._loop_done.wait(grace_s):
            return
        log.critical("the loop thread is stuck: ending the process with the heater %s (exit %d)",
                     "off" if problem is None else "UNKNOWN", exit_code)
        self.datalog.put(Event("stop", f"{cause}: {reason}; the loop thread was stuck, the process was ended "
                                       f"from outside it with the heater {'off' if problem is None else 'UNKNOWN'} "
                                       f"(exit {int(exit_code)})"))
        self.datalog.stop(timeout_s=2.0)
        self.notifier.stopping(message)
        time.sleep(0.2)                 # the journal's writer thread empties its queue
        sys.stderr.flush()
        os._exit(int(exit_code))

    def _on_reload_signal(self) -> None:
        self._reload_wanted = True
        self._service_wake.set()

    def _on_data_log_failure(self, reason: str) -> None:
        """The data log cannot go on (writer thread): the loop stops with the heater at 0 W, exit 7."""
        loop = self.loop
        if loop is not None:
            loop.fail(Fault(FaultCause.DATA_LOG_FAILED, reason))
        self._service_wake.set()

    def _data_log_stop(self) -> int:
        """Before the instruments are touched: no data log, no regulation."""
        self._stop_event(f"data_log_failed: {self.datalog.failure}", ExitCode.DATA_LOG_FAILED)
        return ExitCode.DATA_LOG_FAILED

    # -- service thread: STATUS about once a second, reloads --------------------
    def _service(self) -> None:
        while True:
            self._service_wake.wait(1.0)
            self._service_wake.clear()
            if self._service_stop:
                while self._socket_reloads:
                    self._socket_reloads.popleft().answer(False, "reload refused: the daemon is stopping")
                return
            if self._reload_wanted:
                self._reload_wanted = False
                self.reload()
            if self._socket_reloads:        # those asked for meanwhile share one reading of the file
                asked = [self._socket_reloads.popleft() for _ in range(len(self._socket_reloads))]
                done = self.reload(", ".join(dict.fromkeys(command.sender or "the control socket"
                                                           for command in asked)))
                for command in asked:
                    command.answer(done.ok, done.message)
            if self.loop is not None:
                self.notifier.status(self.loop.status.one_line())

    def reload(self, sender: str = "SIGHUP") -> Command:
        """Validate the configuration file again and hand it to the loop (keeps the old one if bad).

        ``sender`` says who asked, in the journal and the record: a signal (``systemctl reload``
        or ``kill -HUP``), or the control socket's client (``cryod ctl reload``)."""
        self.notifier.reloading()
        try:
            new = self.reload_config()
        except (FileFormatError, ValueError) as error:
            command = Command("reload")
            command.answer(False, f"reload refused, keeping the running configuration: {error}")
        except Exception as error:          # a file the checks did not foresee: refused all the same
            log.exception("reading the configuration for the reload failed")
            command = Command("reload")
            command.answer(False, f"reload refused, keeping the running configuration: reading "
                                  f"{self.config.source or 'the configuration'} failed: {type(error).__name__}: "
                                  f"{str(error)[:300]}")
        else:
            if self.loop is None:
                command = Command("reload")
                command.answer(False, "reload refused: the daemon is still waiting for its instruments; "
                                      "restart it to change the configuration")
            else:
                command = wait_for(self.loop.submit(Command("reload", new, sender=sender)), 10.0)
        if command.ok:
            self.config = new
            self.alarms.reconfigure(new.alarms)
            if self.interfaces is not None:
                self.interfaces.configure(self._interface_settings(new))
            log.info("%s (by %s)", command.message, sender)
        else:
            log.error("%s (by %s)", command.message, sender)
            if self.datalog is not None and not command.message.startswith("kept the running"):
                message = command.message                       # the loop's are written by it
                self.datalog.put(Event("command", (message if message.startswith("reload refused")
                                                   else f"reload refused: {message}") + f" (by {sender})"))
        self.notifier.reloaded(command.message)
        return command

    # -- the control socket before the loop runs ---------------------------------
    def _submit(self, command: Command) -> Command:
        if command.name == "note":
            if self.datalog is None:
                command.answer(False, "note refused: no record is open yet")
            else:
                command.answer(True, write_note(self._put_note, str(command.value), command.sender))
            return command
        if command.name == "reload" and command.value is None:
            # read and checked on the service thread, as for SIGHUP; answered when the loop has taken it
            self._socket_reloads.append(command)
            self._service_wake.set()
            return command
        if command.name == "alarms":
            return self.alarms.submit(command)
        if self.loop is None:
            command.answer(False, f"not running yet: {self._waiting}; commands are taken once the loop runs")
            return command
        return self.loop.submit(command)

    def _put_note(self, event: Event) -> None:
        """A note into the record and the stream (the web page's events), from the socket's thread."""
        self.datalog.put(event)
        self.stream_tap(event)

    def record_path(self) -> str | None:
        """The record being written now (the data log's latest file, as an absolute path), None before the first."""
        paths = self.datalog.paths if self.datalog is not None else []
        return str(paths[-1].absolute()) if paths else None

    def status(self, recent: bool = True) -> DaemonStatus:
        """The daemon's status now; with ``recent``, the figures of the recent past, computed on the caller's
        thread from the live view (the stream leaves them to its subscribers, which have the rows)."""
        interfaces = self._interfaces_status()
        if self.loop is None:
            return DaemonStatus(waiting_for=self._waiting, record_path=self.record_path(),
                                alarm_states=self.alarms.states(), interfaces=interfaces)
        figures = self.live_view.recent() if recent else None
        return DaemonStatus(loop=self.loop.status, record_path=self.record_path(),
                            setpoint_warning=self.loop.setpoint_warning, alarms=tuple(self.alarms.raised()),
                            alarm_states=self.alarms.states(), interfaces=interfaces, recent=figures)

    def _status(self) -> dict:
        return status_json(self.status())

    def _stream_status(self) -> dict:
        return status_json(self.status(recent=False))

    def _interfaces_status(self) -> dict | None:
        """The interfaces process: whether it runs, where it serves, what it says went wrong (None: not wanted)."""
        if self.interfaces is None:
            return None
        reports = [report for report in self.stream.reports() if report.get("pid") == self.interfaces.status()["pid"]]
        report = reports[-1] if reports else {}
        return dict(self.interfaces.status(), web=report.get("web"), lakeshore336=report.get("lakeshore336"),
                    metrics=report.get("metrics"), alarm_hook=report.get("alarm_hook"),
                    problems=report.get("problems", []))

    def _hello(self) -> dict:
        """Who this daemon is, for a subscriber's first line."""
        return {"version": __version__, "pid": os.getpid(), "period_s": self.config.loop.period_s,
                "clock_offset_s": self.clock_offset_s,
                "cooler_rad_s": cooler_rad_s(self.config), "cryostat": self.config.metrics.cryostat,
                "config_file": os.path.abspath(self.config.source) if self.config.source else ""}

    def _lakeshore336_setup(self, config: DaemonConfig) -> Lakeshore336Setup | None:
        """The 336's view of ``config`` (built again after a reload), None without the 336 command set."""
        if config.lakeshore336 is None:
            return None
        built_for, setup = self._lakeshore_setup
        if built_for is not config:
            from cryod.thermometry import load_calibration

            setup = Lakeshore336Setup.from_config(config, load_calibration(config.sensors.flange_calibration),
                                                  load_calibration(config.sensors.ptc_stage_calibration))
            self._lakeshore_setup = (config, setup)
        return setup

    def _interface_settings(self, config: DaemonConfig):
        return interface_settings(config, cooler_rad_s(config), self._lakeshore336_setup(config))

    def _start_interfaces(self, config: DaemonConfig) -> None:
        """The interfaces process, when the configuration asks for any of what it serves; one that cannot be
        started is said in the journal (the cryostat is regulated all the same)."""
        settings = self._interface_settings(config)
        if not settings.wanted:
            return
        self.interfaces = InterfacesProcess(settings, self.stream.last_seq_of, **self.interfaces_options)
        try:
            self.interfaces.start()
        except OSError as error:
            log.error("the interfaces process (web page, 336, metrics, alarm hooks) could not be started: %s", error)
            self.interfaces = None

    # -- the run --------------------------------------------------------------------
    def run(self, duration_s: float | None = None) -> RunResult:
        """Take the locks, open everything, run the loop, close everything with the heater off.

        Instruments that do not answer at start are retried with a growing
        pause (1 s to 60 s) for ``safety.instruments_wait_s`` (without end when
        null) with the heater untouched; a stop signal ends the wait.
        """
        started = time.perf_counter()
        config = self.config
        self._check_watchdog_interval(config)
        locks = self._take_locks(config)
        if locks is None:
            return RunResult(ExitCode.CONFIG, None, [], time.perf_counter() - started)
        instruments: Instruments | None = None
        control_socket: ControlSocketServer | None = None
        realtime: RealtimeSession | None = None
        reading_watchdog: ReadingWatchdog | None = None
        service = threading.Thread(target=self._service, name="cryod-service", daemon=True)
        signals = SignalWatch(self._on_stop_signal, self._on_reload_signal, self._on_signal_seen) \
            if self.install_signal_handlers else None
        restore_exception_hook = None
        exit_code = ExitCode.OK
        try:
            clock_start = self.clock.now()
            wall_start = self.clock.wall_start_s if self.clock.wall_start_s is not None else time.time()
            self.clock_offset_s = wall_start - clock_start
            schema = daemon_schema(config)
            self.datalog = DataLog(config.data.directory, schema, record_metadata(config, schema, self.metadata),
                                   lambda t: wall_start + (t - clock_start), config.loop.period_s,
                                   config.data.fsync_interval_s, warn_free_bytes=int(config.data.warn_free_MB * 1e6),
                                   min_free_bytes=int(config.data.min_free_MB * 1e6),
                                   on_failure=self._on_data_log_failure,
                                   compress_finished=config.data.compress_finished, **self.datalog_options)
            self.datalog.start()
            if signals is not None:
                signals.install()
                restore_exception_hook = install_thread_exception_hook(self._on_thread_exception)
            control_socket = ControlSocketServer(config.control_socket.path, config.control_socket.mode,
                                                 config.control_socket.owner, config.control_socket.group,
                                                 self._submit, self._status, stream=self.stream)
            try:
                control_socket.start()
            except (OSError, KeyError) as error:         # KeyError: an owner or group gone since the checks
                self._stop_event(str(located_error(config, "control_socket.path",
                                                   f"the control socket cannot be served: {error}")), ExitCode.CONFIG)
                raise _NotStarted from None
            self._start_interfaces(config)
            service.start()
            self.notifier.ready("started: opening the instruments")
            opened = self._open_instruments_waiting(config) if self.datalog.failure is None \
                else self._data_log_stop()
            if isinstance(opened, int):
                exit_code = opened
            else:
                opened_instruments, flange_curve, stage_curve = opened
                instruments = self._guard = HeaterGuard(opened_instruments)
                taps = [self.datalog.put, self.live_view, self.stream_tap, *self.row_taps]
                emit = _fan_out([*taps, self.alarms])      # the alarms last: their events follow the row
                self.alarms.attach(emit)
                self.loop = ControlLoop(config, instruments, flange_curve, stage_curve, self.clock,
                                        emit=emit, watchdog=self.notifier.watchdog)
                self.live_view.attach_timing(self.loop.timing.summary)
                if self._stop_reason:
                    self.loop.request_stop(self._stop_reason, *self._stop_as)
                if self.datalog.failure is not None:
                    self.loop.fail(Fault(FaultCause.DATA_LOG_FAILED, self.datalog.failure))
                reading_watchdog = ReadingWatchdog(self.loop, instruments, self.clock, self.datalog.put,
                                                   config.instruments.timeout_s, config.loop.realtime_priority)
                reading_watchdog.start()
                realtime = RealtimeSession(config.loop.realtime_priority, config.loop.lock_memory)
                realtime.start()
                for problem in realtime.problems:
                    log.warning("%s", problem)
                if config.loop.lock_memory:
                    log.info("memory: %s", realtime.memory or "no figure on this system")
                self.notifier.status(f"running: holding the heater off until "
                                     f"{config.safety.valid_readings_to_resume} valid readings")
                log.info("cryod %s: loop period %.0f ms, data in %s, control socket %s", __version__,
                         config.loop.period_s * 1e3, config.data.directory, config.control_socket.path)
                exit_code = self.loop.run(duration_s)
        except _NotStarted:
            exit_code = ExitCode.CONFIG
        except BaseException as error:
            # the heater goes off below (closing the instruments); the record says why, unless the loop did
            if self.datalog is not None and (self.loop is None or self.loop.exit_code is None):
                self._stop_event(f"exception: {type(error).__name__}: {error}", ExitCode.EXCEPTION)
            raise
        finally:
            self._loop_done.set()
            if reading_watchdog is not None:
                reading_watchdog.stop()
            if realtime is not None:
                realtime.end()
            self._service_stop = True
            self._service_wake.set()
            if instruments is not None:
                try:
                    instruments.close()
                except Exception as error:                 # already off in the loop; say so and go on
                    log.critical("closing the instruments failed (the loop had set the heater to 0 W or said it "
                                 "could not): %s", error)
            if self.interfaces is not None:
                self.interfaces.stop()
            if control_socket is not None:
                control_socket.stop()
            if self.datalog is not None:
                self.datalog.stop()
            if signals is not None:
                signals.uninstall()
            if restore_exception_hook is not None:
                restore_exception_hook()
            if service.is_alive():
                service.join(2.0)
            for lock in reversed(locks):
                lock.release()
        status = self.loop.status.one_line() if self.loop else f"not started: {self._waiting}"
        self.notifier.stopping(status)
        if self.datalog is not None and self.datalog.error is not None:
            log.critical("the data log failed: %s", self.datalog.error)
        return RunResult(exit_code, self.loop, self.datalog.written_paths() if self.datalog else [],
                         time.perf_counter() - started)

    def _check_watchdog_interval(self, config: DaemonConfig) -> None:
        """Warn when systemd's watchdog (WATCHDOG_USEC) is shorter than the configuration was checked against."""
        interval = self.notifier.watchdog_interval_s
        if interval is None:
            return
        problem = InstrumentWaits(config.loop.period_s, config.instruments.timeout_s).watchdog_problem(
            interval, "WatchdogSec of this service")
        if problem:
            log.warning("systemd's watchdog may stop this daemon while it waits on an instrument: "
                        "instruments.timeout_s %s", problem)

    def _take_locks(self, config: DaemonConfig) -> list | None:
        """This cryostat's lock, then its instruments' (when real): the locks held, or None when another daemon
        holds one (said in the journal; nothing was touched)."""
        lock = InstanceLock(config.control_socket.path)
        try:
            lock.acquire()
        except AlreadyRunning as error:
            self.not_started = str(error)
            log.critical("not started: %s", error)
            return None
        except OSError as error:                # a folder cryod run's checks found usable a moment ago
            log.critical("not started: %s", located_error(config, "control_socket.path",
                                                          f"the lock {lock.path} cannot be taken: {error}"))
            return None
        if self.instrument_addresses is None:
            return [lock]
        try:
            instrument_locks = InstrumentLocks(config.instruments.lock_directory, self.instrument_addresses(config),
                                               config.source)
            instrument_locks.acquire()
        except (AlreadyRunning, OSError, ValueError) as error:
            lock.release()
            log.critical("not started: %s", error)
            return None
        return [lock, instrument_locks]

    def _open_instruments_waiting(self, config: DaemonConfig):
        """The opened instruments and curves, or the exit code when they never came (or a stop came first).

        With ``safety.instruments_wait_s`` the last attempt is made when that time is up, not
        before: the pause before it is shortened to fit."""
        wait_limit = config.safety.instruments_wait_s
        first_try = self.clock.now()
        give_up_at = math.inf if wait_limit is None else first_try + wait_limit
        pause, attempt = 1.0, 0
        while True:
            attempt += 1
            if self.datalog.failure is not None:
                return self._data_log_stop()
            try:
                return self.open_instruments(config, self.clock)
            except IdentityMismatch as error:
                self._stop_event(f"{error}: another instrument answers at a configured address", ExitCode.CONFIG)
                return ExitCode.CONFIG
            except InstrumentError as error:
                now = self.clock.now()
                waited = now - first_try
                if now >= give_up_at:
                    self._stop_event(f"instruments out of reach for {waited:.1f} s "
                                     f"(safety.instruments_wait_s {wait_limit:g}): {error}",
                                     ExitCode.INSTRUMENTS_LOST)
                    return ExitCode.INSTRUMENTS_LOST
                retry_at = min(now + pause, give_up_at)
                self._waiting = f"waiting for the instruments (attempt {attempt}, {waited:.0f} s): {error}"
                log.warning("instruments out of reach, heater untouched; retrying in %.3g s: %s", retry_at - now,
                            error)
                self.datalog.put(Event("waiting", f"instruments out of reach, retrying in {retry_at - now:.3g} s: "
                                                  f"{error}"))
                self.notifier.status(self._waiting)
            if self._pause_until(retry_at):
                exit_code, cause = self._stop_as
                self._stop_event(f"{cause}: {self._stop_reason}", exit_code)
                return exit_code
            pause = min(2.0 * pause, MAX_RETRY_PAUSE_S)

    def _pause_until(self, end_s: float) -> bool:
        """Wait on the clock until ``end_s``, keeping the watchdog fed; True when a stop was asked for meanwhile."""
        while not self._stop_reason and self.clock.now() < end_s:
            self.clock.sleep_until(min(end_s, self.clock.now() + 1.0))
            self.notifier.watchdog()
        return bool(self._stop_reason)

    def _stop_event(self, reason: str, exit_code: int) -> None:
        level = logging.INFO if exit_code == ExitCode.OK else logging.CRITICAL
        log.log(level, "stopping before the loop ran (exit %d): %s", exit_code, reason)
        self.datalog.put(Event("stop", f"{reason} (exit {int(exit_code)})"))


def stop_grace_s(config: DaemonConfig) -> float:
    """How long the loop has to stop by itself once told to (s): a period and one instrument call to its
    timeout (a tick asked to stop after its readings sets no new power, so a loop that answers stops
    within that); after it, the heater is switched off from outside the loop."""
    return config.loop.period_s + config.instruments.timeout_s


def cooler_rad_s(config: DaemonConfig) -> float:
    """The cooler's angular frequency (rad/s) in the controller's model (the feedforward's, else the shipped)."""
    return controller_model(config.control)[0].ptc.angular_frequency_rad_s


def _fan_out(receivers: list[Callable]) -> Callable:
    def emit(item) -> None:
        for receiver in receivers:
            receiver(item)
    return emit


def config_or_exit(path: str | Path, stderr) -> DaemonConfig | None:
    """Load the configuration, or print why not (file, line, key) and return None."""
    try:
        return load_config(path)
    except FileFormatError as error:
        print(f"cryod: configuration not usable, nothing was started: {error}", file=stderr)
        return None


__all__ = ["Daemon", "RunResult", "record_metadata", "config_or_exit", "stop_grace_s"]
