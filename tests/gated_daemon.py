"""The whole daemon on the simulated bench, its loop held after every row until a test lets it go on.

The daemon runs in a thread on virtual time with the drivers on the in-process simulated
instruments, its data log and its real control socket. A row tap holds the loop thread after
each row, so a test decides how many ticks pass while its clients talk to the socket, and can
look at the regulator while the loop stands still between two ticks.
"""

from __future__ import annotations

import dataclasses
import threading
import time

from cryod.config import load_config
from cryod.model import load_model
from cryod.records.columns import Event, Row
from drivers.clock import VirtualClock
from cryod.service.daemon import Daemon
from cryod.service.notify import SystemdNotifier
from cryod.service.simulation import SimulatedInstrumentsOpener
from tests.conftest import CONFIG


class TickGate:
    """Row tap: holds the loop after each row until :meth:`run_ticks` lets more ticks run."""

    def __init__(self):
        self.rows: list[Row] = []
        self.events: list[tuple[int, Event]] = []
        self._allowed = threading.Semaphore(0)
        self._changed = threading.Condition()
        self._open = False

    def __call__(self, item) -> None:
        if not isinstance(item, Row):
            self.events.append((len(self.rows), item))       # (rows before it, event)
            return
        with self._changed:
            self.rows.append(item)
            self._changed.notify_all()
        if not self._open:
            self._allowed.acquire()

    def run_ticks(self, count: int = 1, timeout_s: float = 30.0) -> None:
        """Let ``count`` more ticks run and wait for their rows."""
        with self._changed:
            target = len(self.rows) + count
            for _ in range(count):
                self._allowed.release()
            if not self._changed.wait_for(lambda: len(self.rows) >= target, timeout_s):
                raise AssertionError(f"the loop did not run {count} more tick(s) within {timeout_s:g} s")

    def wait_for_first_row(self, timeout_s: float = 60.0) -> None:
        with self._changed:
            if not self._changed.wait_for(lambda: self.rows, timeout_s):
                raise AssertionError("the daemon made no row")

    def open(self) -> None:
        """Let the loop run freely from now on."""
        self._open = True
        self._allowed.release()


class GatedDaemon:
    """``with GatedDaemon(tmp_path) as daemon:`` a regulating daemon whose loop stands between two ticks."""

    def __init__(self, tmp_path, sections: dict | None = None, **control):
        config = load_config(CONFIG / "cryod.yaml")
        config = dataclasses.replace(config, **(sections or {}))        # e.g. web, lakeshore336
        self.config = dataclasses.replace(
            config,
            loop=dataclasses.replace(config.loop, realtime_priority=0, lock_memory=False),
            data=dataclasses.replace(config.data, directory=tmp_path / "data"),
            control_socket=dataclasses.replace(config.control_socket, path=tmp_path / "control.sock"),
            simulation=dataclasses.replace(config.simulation, transport="in-process"),
            control=dataclasses.replace(config.control, **control))
        self.socket_path = self.config.control_socket.path
        self.gate = TickGate()
        #: Where the interfaces process (web page, 336, metrics, hooks) writes its journal lines.
        self.interfaces_log = tmp_path / "interfaces.log"
        self._interfaces_stderr = open(self.interfaces_log, "w")
        self.daemon = Daemon(self.config, SimulatedInstrumentsOpener(load_model(), seed=4), VirtualClock(),
                             notifier=SystemdNotifier({}), row_taps=[self.gate], install_signal_handlers=False,
                             interfaces_options={"stderr": self._interfaces_stderr})
        self.result = None
        self._thread = threading.Thread(target=self._run, name="gated-daemon", daemon=True)

    def _run(self) -> None:
        self.result = self.daemon.run(3600.0)

    def __enter__(self) -> "GatedDaemon":
        self._thread.start()
        self.gate.wait_for_first_row()
        self.gate.run_ticks(self.config.safety.valid_readings_to_resume + 1)     # past the start-up hold
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def stop(self) -> None:
        """Stop the daemon (heater off, files closed) and wait for it."""
        if self._thread.is_alive():
            self.daemon.loop.request_stop("test finished")
            self.gate.open()
            self._thread.join(60.0)
        self._interfaces_stderr.close()

    def interface(self, name: str, timeout_s: float = 30.0) -> str:
        """Where the interfaces process serves ``name`` (``web``, ``lakeshore336``, ``metrics``), once it has said so
        and has the daemon's stream."""
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.daemon._interfaces_status() or {}
            if status.get(name):
                return status[name]
            assert time.monotonic() < deadline, f"the interfaces process did not serve {name} within {timeout_s:g} s:" \
                                                f" {status}; its journal: {self.interfaces_journal()}"
            time.sleep(0.02)

    def port(self, name: str) -> int:
        """The port the interfaces process serves ``name`` on."""
        return int(self.interface(name).rstrip("/").removesuffix("/metrics").rpartition(":")[2])

    def interfaces_journal(self) -> str:
        """What the interfaces process has written to its journal so far."""
        self._interfaces_stderr.flush()
        return self.interfaces_log.read_text()

    @property
    def loop(self):
        return self.daemon.loop

    def regulator_state(self) -> tuple:
        """What the operator's commands set: loop state, mode, target, ramp, manual power, feedforward switch
        (read while the loop stands between two ticks)."""
        regulator = self.loop.regulator
        feedforward = regulator.term("feedforward")
        return (str(self.loop.state), str(regulator.mode), regulator.ramp.target_K, regulator.ramp.rate_K_per_min,
                regulator.manual_power_w, None if feedforward is None else feedforward.switched_on)
