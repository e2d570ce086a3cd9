"""The daemon: configuration, instruments, loop, data log, control socket, systemd, signals.

``cryod run`` and ``cryod --simulate`` both come here; they differ only in
the instruments handed over (real ones, or drivers talking to simulated ones)
and the clock.

Threads: the main thread runs the control loop and nothing else. The data
log writer, the control socket, the status/reload service thread and the log
listener run beside it and talk to the loop through queues and snapshots.
"""

from __future__ import annotations

import collections
import functools
import logging
import platform
import signal
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from cryod import __version__
from cryod.config import DaemonConfig, load_config, located_error
from cryod.records.datalog import DataLog
from cryod.records.columns import Event, RowSchema
from cryod.service.commands import Command, wait_for
from cryod.service.faults import ExitCode, Fault, FaultCause
from cryod.service.instance_lock import AlreadyRunning, InstanceLock
from cryod.service.live_view import LiveView
from cryod.service.loop import ControlLoop, Instruments, daemon_schema
from cryod.service.realtime import RealtimeSession
from cryod.service.control_socket import ControlSocketServer
from cryod.service.notify import SystemdNotifier
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
    log_paths: list[Path]
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
        SIGTERM/SIGINT stop, SIGHUP reloads (main thread only).
    reload_config : callable, optional
        Reads and validates the configuration again on reload (default:
        :func:`cryod.config.load_config` of the file it came from);
        ``cryod --simulate`` passes one that applies its command-line overrides.
    datalog_options : dict, optional
        More keyword arguments of :class:`~cryod.records.datalog.DataLog` (tests: a fake disk's
        ``free_space``).
    """

    def __init__(self, config: DaemonConfig, open_instruments: Callable, clock: Clock,
                 notifier: SystemdNotifier | None = None, metadata: dict | None = None,
                 row_taps: list[Callable] | None = None, install_signal_handlers: bool = True,
                 reload_config: Callable[[], DaemonConfig] | None = None, datalog_options: dict | None = None):
        self.config = config
        self.reload_config = reload_config or (lambda: load_config(self.config.source))
        self.open_instruments = open_instruments
        self.clock = clock
        self.notifier = notifier or SystemdNotifier()
        self.metadata = metadata or {}
        self.row_taps = row_taps or []
        self.datalog_options = datalog_options or {}      # e.g. a fake disk's free space, for tests
        self.install_signal_handlers = install_signal_handlers
        self.loop: ControlLoop | None = None
        self.datalog: DataLog | None = None
        #: The latest row and faults, for the status line and the metrics endpoint.
        self.live_view = LiveView(config.loop.period_s, cooler_rad_s(config))
        self._reload_wanted = False
        self._socket_reloads: collections.deque[Command] = collections.deque()   # "reload" from the socket
        self._stop_reason: str | None = None
        self._waiting = "opening the instruments"
        self._service_stop = False
        self._service_wake = threading.Event()      # a reload or the stop

    # -- signals ----------------------------------------------------------------
    def _on_stop_signal(self, number, frame) -> None:
        self._stop_reason = f"{signal.Signals(number).name} received"
        if self.loop is not None:
            self.loop.request_stop(self._stop_reason)

    def _on_reload_signal(self, number, frame) -> None:
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
        if command.name == "reload" and command.value is None:
            # read and checked on the service thread, as for SIGHUP; answered when the loop has taken it
            self._socket_reloads.append(command)
            self._service_wake.set()
            return command
        if self.loop is None:
            command.answer(False, f"not running yet: {self._waiting}; commands are taken once the loop runs")
            return command
        return self.loop.submit(command)

    def _status(self) -> dict:
        if self.loop is None:
            return {"state": "waiting", "message": self._waiting, "heater_W": None}
        status = self.loop.status.as_dict()
        # figures over the recent past, computed on this (the socket's) thread
        status["T2_average_K"] = self.live_view.flange_average_K()
        status["line_amplitude_K"] = self.live_view.line_amplitude_K()
        return status

    # -- the run --------------------------------------------------------------------
    def run(self, duration_s: float | None = None) -> RunResult:
        """Take the lock, open everything, run the loop, close everything with the heater off.

        Instruments that do not answer at start are retried with a growing
        pause (1 s to 60 s) for ``safety.instruments_wait_s`` (without end when
        null) with the heater untouched; a stop signal ends the wait.
        """
        started = time.perf_counter()
        config = self.config
        lock = InstanceLock(config.control_socket.path)
        try:
            lock.acquire()
        except AlreadyRunning as error:
            log.critical("not started: %s", error)
            return RunResult(ExitCode.CONFIG, None, [], time.perf_counter() - started)
        except OSError as error:                # a folder cryod run's checks found usable a moment ago
            log.critical("not started: %s", located_error(config, "control_socket.path",
                                                          f"the lock {lock.path} cannot be taken: {error}"))
            return RunResult(ExitCode.CONFIG, None, [], time.perf_counter() - started)
        instruments: Instruments | None = None
        control_socket: ControlSocketServer | None = None
        realtime: RealtimeSession | None = None
        metrics = None
        service = threading.Thread(target=self._service, name="cryod-service", daemon=True)
        previous_handlers = {}
        exit_code = ExitCode.OK
        try:
            clock_start = self.clock.now()
            wall_start = time.time()
            schema = daemon_schema(config)
            self.datalog = DataLog(config.data.directory, schema, record_metadata(config, schema, self.metadata),
                                   lambda t: wall_start + (t - clock_start), config.loop.period_s,
                                   config.data.fsync_interval_s, warn_free_bytes=int(config.data.warn_free_MB * 1e6),
                                   min_free_bytes=int(config.data.min_free_MB * 1e6),
                                   on_failure=self._on_data_log_failure,
                                   compress_finished=config.data.compress_finished, **self.datalog_options)
            self.datalog.start()
            control_socket = ControlSocketServer(config.control_socket.path, config.control_socket.mode,
                                                 config.control_socket.owner, config.control_socket.group,
                                                 self._submit, self._status)
            try:
                control_socket.start()
            except (OSError, KeyError) as error:         # KeyError: an owner or group gone since the checks
                self._stop_event(str(located_error(config, "control_socket.path",
                                                   f"the control socket cannot be served: {error}")), ExitCode.CONFIG)
                raise _NotStarted from None
            if config.metrics.address is not None:
                from cryod.service.metrics_export import MetricsEndpoint

                metrics = MetricsEndpoint(self.live_view, config.metrics.address, config.metrics.cryostat)
                try:
                    metrics.start()
                except OSError as error:      # monitoring is not worth a cryostat: say so and regulate
                    log.error("no metrics endpoint: %s", error)
                    metrics = None
                else:
                    log.info("Prometheus metrics on http://%s:%d/metrics", metrics.host, metrics.port)
            if self.install_signal_handlers:
                for number, handler in ((signal.SIGTERM, self._on_stop_signal), (signal.SIGINT, self._on_stop_signal),
                                        (signal.SIGHUP, self._on_reload_signal)):
                    previous_handlers[number] = signal.signal(number, handler)
            service.start()
            self.notifier.ready("started: opening the instruments")
            opened = self._open_instruments_waiting(config) if self.datalog.failure is None \
                else self._data_log_stop()
            if isinstance(opened, int):
                exit_code = opened
            else:
                instruments, flange_curve, stage_curve = opened
                taps = [self.datalog.put, self.live_view, *self.row_taps]
                self.loop = ControlLoop(config, instruments, flange_curve, stage_curve, self.clock,
                                        emit=_fan_out(taps), watchdog=self.notifier.watchdog)
                self.live_view.attach_timing(self.loop.timing.summary)
                if self._stop_reason:
                    self.loop.request_stop(self._stop_reason)
                if self.datalog.failure is not None:
                    self.loop.fail(Fault(FaultCause.DATA_LOG_FAILED, self.datalog.failure))
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
        finally:
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
            if control_socket is not None:
                control_socket.stop()
            if metrics is not None:
                metrics.stop()
            if self.datalog is not None:
                self.datalog.stop()
            for number, handler in previous_handlers.items():
                signal.signal(number, handler)
            if service.is_alive():
                service.join(2.0)
            lock.release()
        status = self.loop.status.one_line() if self.loop else f"not started: {self._waiting}"
        self.notifier.stopping(status)
        if self.datalog is not None and self.datalog.error is not None:
            log.critical("the data log failed: %s", self.datalog.error)
        return RunResult(exit_code, self.loop, list(self.datalog.paths) if self.datalog else [],
                         time.perf_counter() - started)

    def _open_instruments_waiting(self, config: DaemonConfig):
        """The opened instruments and curves, or the exit code when they never came (or a stop came first)."""
        wait_limit = config.safety.instruments_wait_s
        first_try = self.clock.now()
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
                waited = self.clock.now() - first_try
                if wait_limit is not None and waited + pause > wait_limit:
                    self._stop_event(f"instruments out of reach for {waited:.0f} s "
                                     f"(safety.instruments_wait_s {wait_limit:g}): {error}",
                                     ExitCode.INSTRUMENTS_LOST)
                    return ExitCode.INSTRUMENTS_LOST
                self._waiting = f"waiting for the instruments (attempt {attempt}, {waited:.0f} s): {error}"
                log.warning("instruments out of reach, heater untouched; retrying in %.0f s: %s", pause, error)
                self.datalog.put(Event("waiting", f"instruments out of reach, retrying in {pause:.0f} s: {error}"))
                self.notifier.status(self._waiting)
            if self._pause(pause):
                self._stop_event(self._stop_reason, ExitCode.OK)
                return ExitCode.OK
            pause = min(2.0 * pause, MAX_RETRY_PAUSE_S)

    def _pause(self, duration_s: float) -> bool:
        """Wait on the clock, keeping the watchdog fed; True when a stop was asked for meanwhile."""
        end = self.clock.now() + duration_s
        while not self._stop_reason and self.clock.now() < end:
            self.clock.sleep_until(min(end, self.clock.now() + 1.0))
            self.notifier.watchdog()
        return bool(self._stop_reason)

    def _stop_event(self, reason: str, exit_code: int) -> None:
        level = logging.INFO if exit_code == ExitCode.OK else logging.CRITICAL
        log.log(level, "stopping before the loop ran (exit %d): %s", exit_code, reason)
        self.datalog.put(Event("stop", f"{reason} (exit {int(exit_code)})"))


def cooler_rad_s(config: DaemonConfig) -> float:
    """The cooler's angular frequency (rad/s) in the controller's model (the feedforward's, else the shipped)."""
    from cryod.model import DEFAULT_MODEL_PATH

    for name, settings in config.control.terms:
        if name == "feedforward" and getattr(settings, "model", None) is not None:
            return settings.model.ptc.angular_frequency_rad_s
    return _model_cooler_rad_s(DEFAULT_MODEL_PATH)


@functools.lru_cache(maxsize=4)
def _model_cooler_rad_s(path) -> float:
    from cryod.model import load_model

    return load_model(path).ptc.angular_frequency_rad_s


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


__all__ = ["Daemon", "RunResult", "record_metadata", "config_or_exit"]
