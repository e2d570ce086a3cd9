"""The interfaces process: the web page, the Lake Shore 336 command set, the metrics and the alarm hooks, apart.

What the lab watches and drives the daemon through, other than the control socket, runs in a
second process (``python -m cryod.interfaces``, :mod:`cryod.interfaces`), started by the daemon,
as its user, and started again when it ends without being asked to. It reads the daemon through
the live stream of the control socket (:mod:`cryod.service.stream`) and sends commands through
the control socket with its client's identity; nothing it does (a megabyte of JSON, a hook's
output, a hang, a crash) can hold the loop's thread, which shares no interpreter with it.

Its settings (:class:`InterfaceSettings`) reach it on its standard input, a pipe only the daemon
writes: one length-prefixed pickle at the start and one more after each reload. When that pipe
closes (the daemon stopped, or died), the process ends.
"""

from __future__ import annotations

import logging
import pickle
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from cryod.alarms.settings import AlarmHook
from cryod.config import DaemonConfig, Lakeshore336Config, WebConfig

log = logging.getLogger("cryod.interfaces")

#: The first pause before starting the process again after it ended, and the longest (s).
RESTART_FIRST_S, RESTART_LONGEST_S = 1.0, 60.0
#: A process that ran this long before it ended is started again after the first pause (s).
RAN_WELL_S = 60.0
#: How long the process has to end after its settings pipe closes, then after SIGTERM (s).
END_GRACE_S = 3.0
#: The frame header of a settings message: its length.
_LENGTH = struct.Struct(">Q")
#: The largest settings message taken (bytes).
MAX_SETTINGS_BYTES = 16 * 1024 * 1024


@dataclass(frozen=True)
class InterfaceSettings:
    """What the interfaces process serves, from the daemon's configuration in force.

    Attributes
    ----------
    socket_path : pathlib.Path
        The daemon's control socket: its stream and its commands.
    period_s : float
        The loop's period (s).
    cooler_rad_s : float
        The cooler's angular frequency in the controller's model (rad/s): the line's amplitude.
    heater_max_w : float
        R * I_max^2 (W): the top of the web page's heater chart.
    cryostat : str
        ``metrics.cryostat``.
    web, lakeshore336 : WebConfig, Lakeshore336Config or None
    metrics_address : str or None
        ``metrics.address``.
    alarm_hook : AlarmHook or None
        ``alarms.hook``.
    lakeshore336_setup : object
        The :class:`~cryod.service.lakeshore336.Lakeshore336Setup` of the configuration in force.
    config_source : str
        The configuration file (for messages).
    """

    socket_path: Path
    period_s: float
    cooler_rad_s: float
    heater_max_w: float = 0.5
    cryostat: str = ""
    web: WebConfig | None = None
    lakeshore336: Lakeshore336Config | None = None
    metrics_address: str | None = None
    alarm_hook: AlarmHook | None = None
    lakeshore336_setup: object = None
    config_source: str = ""

    @property
    def wanted(self) -> bool:
        """Whether anything is configured that the process serves."""
        return any(item is not None for item in (self.web, self.lakeshore336, self.metrics_address, self.alarm_hook))


def interface_settings(config: DaemonConfig, cooler_rad_s: float, lakeshore336_setup=None) -> InterfaceSettings:
    """The interfaces' settings from a daemon configuration."""
    return InterfaceSettings(socket_path=Path(config.control_socket.path), period_s=config.loop.period_s,
                             cooler_rad_s=cooler_rad_s, heater_max_w=config.heater.max_power_w,
                             cryostat=config.metrics.cryostat, web=config.web,
                             lakeshore336=config.lakeshore336, metrics_address=config.metrics.address,
                             alarm_hook=config.alarms.hook, lakeshore336_setup=lakeshore336_setup,
                             config_source=str(config.source or ""))


def write_settings(pipe, settings: InterfaceSettings) -> None:
    """One settings message on ``pipe`` (a binary file)."""
    data = pickle.dumps(settings, protocol=pickle.HIGHEST_PROTOCOL)
    pipe.write(_LENGTH.pack(len(data)) + data)
    pipe.flush()


def read_settings(pipe) -> InterfaceSettings | None:
    """The next settings message from ``pipe`` (the daemon's end), None when it closed."""
    header = pipe.read(_LENGTH.size)
    if len(header) < _LENGTH.size:
        return None
    (length,) = _LENGTH.unpack(header)
    if length > MAX_SETTINGS_BYTES:
        raise ValueError(f"a settings message of {length} bytes: not from a cryod daemon")
    data = pipe.read(length)
    if len(data) < length:
        return None
    settings = pickle.loads(data)         # the daemon's own pipe to its own child: trusted
    if not isinstance(settings, InterfaceSettings):
        raise ValueError(f"not interface settings: {type(settings).__name__}")
    return settings


class InterfacesProcess:
    """Starts the interfaces process, starts it again when it ends unasked, hands it new settings, ends it.

    Parameters
    ----------
    settings : InterfaceSettings
    last_seq : callable, optional
        The sequence number of the last event the ended process had taken (``last_seq(pid)``, from the
        stream's reports), so that the next one asks for what it missed.
    stderr : file, optional
        Where the process's log lines go (default: the daemon's standard error, the journal).
    """

    def __init__(self, settings: InterfaceSettings, last_seq: Callable[[int], int | None] | None = None,
                 stderr=None):
        self.settings = settings
        self.last_seq = last_seq or (lambda pid: None)
        self.stderr = stderr
        self.process: subprocess.Popen | None = None
        #: Times it was started again after ending unasked, and how the last one ended.
        self.restarts = 0
        self.last_exit: str | None = None
        self._stopping = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the process and watch it from a thread of its own."""
        process = self._spawn(None)
        self._thread = threading.Thread(target=self._watch, args=(process,), name="cryod-interfaces", daemon=True)
        self._thread.start()

    def _spawn(self, after: int | None) -> subprocess.Popen:
        command = [sys.executable, "-m", "cryod.interfaces"] + ([] if after is None else ["--after", str(after)])
        with self._lock:
            process = self.process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                                      stderr=self.stderr, close_fds=True)
            try:
                write_settings(process.stdin, self.settings)
            except OSError:                     # it ended at once: the watcher says why
                pass
        log.info("interfaces process started (pid %d)", process.pid)
        return process

    def _watch(self, process: subprocess.Popen) -> None:
        """Wait for ``process`` (the one started) to end; start it again after a pause, and so on."""
        pause_s = RESTART_FIRST_S
        while not self._stopping.is_set():
            started = time.monotonic()
            code = process.wait()
            if self._stopping.is_set():
                return
            self.last_exit = f"exit {code}" if code >= 0 else f"signal {-code}"
            ran_s = time.monotonic() - started
            pause_s = RESTART_FIRST_S if ran_s >= RAN_WELL_S else pause_s
            log.error("the interfaces process (pid %d) ended (%s) after %.0f s: the web page, the 336 command set, "
                      "the metrics and the alarm hooks are off until it is started again in %.0f s; regulation "
                      "goes on", process.pid, self.last_exit, ran_s, pause_s)
            if self._stopping.wait(pause_s):
                return
            self.restarts += 1
            try:
                process = self._spawn(self.last_seq(process.pid))
            except OSError as error:
                log.error("the interfaces process could not be started again: %s", error)
            pause_s = min(2.0 * pause_s, RESTART_LONGEST_S)

    def configure(self, settings: InterfaceSettings) -> None:
        """New settings (a reload), handed to the running process."""
        self.settings = settings
        with self._lock:
            process = self.process
            if process is None or process.poll() is not None:
                return
            try:
                write_settings(process.stdin, settings)
            except OSError as error:
                log.warning("the interfaces process did not take the new settings (%s); it gets them when it is "
                            "started again", error)

    def status(self) -> dict:
        """For the daemon's status: the process, whether it runs, its restarts and how the last one ended."""
        process = self.process
        return {"pid": None if process is None else process.pid,
                "running": process is not None and process.poll() is None,
                "restarts": self.restarts, "last_exit": self.last_exit}

    def stop(self) -> None:
        """End the process: its settings pipe closed, then SIGTERM, then SIGKILL, each after :data:`END_GRACE_S`."""
        self._stopping.set()
        with self._lock:
            process = self.process
        if process is None:
            return
        try:
            if process.stdin is not None:
                process.stdin.close()
        except OSError:
            pass
        for end in (None, process.terminate, process.kill):
            if end is not None:
                try:
                    end()
                except OSError:
                    pass
            try:
                process.wait(END_GRACE_S)
                break
            except subprocess.TimeoutExpired:
                continue
        if self._thread is not None:
            self._thread.join(END_GRACE_S)


__all__ = ["InterfaceSettings", "InterfacesProcess", "interface_settings", "read_settings", "write_settings"]
