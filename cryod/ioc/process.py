"""``cryod ioc [--config FILE] [--socket PATH]``: cryod's EPICS IOC, a process of its own.

It finds the daemon as ``cryod ctl`` does (``--socket``; else ``control_socket.path`` of ``--config``;
else the service's socket or this user's dry run's), reads the daemon's first stream line (who it
is, its configuration file, its clock's offset to the wall clock), reads the ``ioc`` section of the
configuration (``--config``, else the file the daemon runs on), builds the records, sets the access
security rules, starts EPICS (Channel Access and pvAccess, on the ports and interfaces the ``EPICS_*``
environment variables give) and then follows the daemon's stream: every row updates the per-row
readings, every line the rest. A lost stream makes every reading INVALID until the link is back
(:class:`~cryod.interfaces.daemon_link.DaemonLink` connects again by itself, as in the interfaces
process); the IOC ends on SIGTERM or SIGINT.

Exit codes: 0 stopped, 2 a configuration that cannot be used (no ``ioc`` section, a bad access
security file), 3 no daemon found or answering within :data:`CONNECT_WAIT_S`.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

from cryod.config import DaemonConfig, load_config
from cryod.interfaces.daemon_link import MAX_STREAM_LINE, DaemonLink
from cryod.interfaces.mirror import DaemonMirror
from cryod.records.columns import Row
from cryod.service.settling import SettlingWatch

log = logging.getLogger("cryod.ioc")

#: How long the IOC waits for the daemon's first answer at start before it gives up (exit 3; systemd starts
#: it again), s.
CONNECT_WAIT_S = 60.0


class IocError(Exception):
    """The IOC cannot start; ``code`` is the exit code, the message says why."""

    def __init__(self, message: str, code: int):
        super().__init__(message)
        self.code = code


async def first_line(socket_path: Path) -> dict:
    """The daemon's first stream line: its ``hello`` (version, pid, period, cooler frequency, clock offset,
    configuration file), its recent rows and events, its status."""
    reader, writer = await asyncio.open_unix_connection(str(socket_path), limit=MAX_STREAM_LINE)
    try:
        writer.write(b"subscribe\n")
        await writer.drain()
        first = json.loads(await asyncio.wait_for(reader.readline(), 10.0) or b"null")
    finally:
        writer.close()
    if not isinstance(first, dict) or not first.get("ok"):
        message = first.get("message") if isinstance(first, dict) else "no answer"
        raise ConnectionError(f"the daemon did not take a subscription: {message}")
    return first


def wait_for_daemon(socket_path: Path, wait_s: float = CONNECT_WAIT_S) -> dict:
    """The daemon's first stream line, asked again until it answers or ``wait_s`` passed (IocError, exit 3)."""
    deadline = time.monotonic() + wait_s
    said = False
    while True:
        try:
            return asyncio.run(first_line(socket_path))
        except (OSError, ConnectionError, ValueError, asyncio.TimeoutError) as error:
            if time.monotonic() > deadline:
                raise IocError(f"no cryod daemon answers at {socket_path} ({error}); is it running?", 3) from None
            if not said:
                log.warning("waiting for the daemon at %s: %s", socket_path, error)
                said = True
            time.sleep(1.0)


def ioc_configuration(config_path: Path | None, hello: dict) -> DaemonConfig:
    """The configuration whose ``ioc`` section is served: ``--config``, else the daemon's own file."""
    path = config_path or (Path(hello["config_file"]) if hello.get("config_file") else None)
    if path is None:
        raise IocError("the daemon does not say which configuration it runs on; give --config FILE", 2)
    config = load_config(path)
    if config.ioc is None:
        raise IocError(f"{path}: no ioc section, so the IOC is off (add ioc: {{prefix: \"CRYO1:\"}}; "
                       f"docs/how-to/epics-bluesky.md, \"EPICS and Bluesky\")", 2)
    return config


class Ioc:
    """The running IOC: the link to the daemon, the mirror of its state, the records.

    Built in the process's main thread before ``iocInit``; :meth:`start` then runs the link on the
    dispatcher's event loop.
    """

    def __init__(self, config: DaemonConfig, socket_path: Path, first: dict, rules_folder: Path):
        from softioc import softioc  # noqa: F401  (EPICS base loaded before the records are declared)

        from cryod.ioc.access_security import rules_in_force, use_rules
        from cryod.ioc.client_identity import ClientIdentity
        from cryod.ioc.records import ReadingRecords
        from cryod.ioc.settings import SettingRecords

        self.config = config
        ioc = config.ioc
        hello = first.get("hello") or {}
        self.mirror = DaemonMirror(float(hello.get("period_s") or config.loop.period_s),
                                   float(hello.get("cooler_rad_s") or 10.83))
        self.mirror.first(first)                # the settings' first values are what the daemon holds
        self.link = DaemonLink(socket_path, self.mirror, self.report)
        self.watch = SettlingWatch(ioc.stable_tolerance_K, ioc.stable_hold_s)
        self.identity = ClientIdentity()
        self.readings = ReadingRecords(ioc.prefix, {"HEATER_MAX": config.heater.max_power_w,
                                                    "STABLE_TOL": ioc.stable_tolerance_K,
                                                    "STABLE_HOLD": ioc.stable_hold_s}, elsewhere={"MESSAGE"})
        self.settings = SettingRecords(ioc.prefix, ioc, config.control, self.link, self.mirror, self.identity,
                                       self.readings.message)
        self.rules, self.rules_said = rules_in_force(ioc.writable, ioc.access_security_file, rules_folder)
        use_rules(self.rules)
        self.identity.register()
        self.mirror.on_row(self._row)
        self._was_connected = False

    def report(self) -> dict:
        """What the IOC says of itself to the daemon (its ``interfaces`` reports)."""
        return {"pid": os.getpid(), "epics_ioc": self.config.ioc.prefix, "problems": []}

    def _row(self, row: Row) -> None:
        from cryod.ioc.readings import row_values

        self.readings.row(row, row_values(row))

    def _line(self) -> None:
        """After each line of the stream: the status' readings and the alarms."""
        from cryod.ioc.readings import status_values

        if not self.mirror.connected:
            if self._was_connected:
                self.readings.lost()
                log.warning("lost the daemon's stream: every reading is INVALID (COMM) until it is back")
            self._was_connected = False
            return
        self._was_connected = True
        self.readings.clock_offset_s = float(self.mirror.hello.get("clock_offset_s") or 0.0)
        status = self.mirror.status()
        settling = self.watch.observe(status)
        self.readings.status(status, settling, status_values(status, settling, True))
        self.settings.follow(status)

    async def follow(self) -> None:
        """Update the records at each line of the stream, for as long as the IOC runs."""
        link = asyncio.ensure_future(self.link.run())
        try:
            while True:
                changed = self.mirror.changed
                await changed.wait()
                try:
                    self._line()
                except Exception:                      # one bad line must not stop the IOC
                    log.exception("a line of the daemon's stream could not be shown")
        finally:
            link.cancel()


def run(config_path: Path | None, socket_path: Path | None) -> int:
    """``cryod ioc``: the exit code."""
    from cryod.service.discovery import find_daemon_socket

    try:
        if socket_path is None and config_path is not None:
            socket_path = load_config(config_path).control_socket.path
        deadline = time.monotonic() + CONNECT_WAIT_S
        while socket_path is None:               # a daemon started at the same time makes its socket soon
            try:
                socket_path = find_daemon_socket()
            except ConnectionError as error:
                if time.monotonic() > deadline:
                    raise IocError(str(error), 3) from None
                time.sleep(1.0)
        first = wait_for_daemon(Path(socket_path))
        config = ioc_configuration(config_path, first.get("hello") or {})
    except IocError as error:
        print(f"cryod ioc: {error}", file=sys.stderr)
        return error.code
    except ConnectionError as error:
        print(f"cryod ioc: {error}", file=sys.stderr)
        return 3
    except Exception as error:         # a configuration that cannot be read: its message names file, line, key
        if type(error).__name__ == "FileFormatError":
            print(f"cryod ioc: configuration not usable: {error}", file=sys.stderr)
            return 2
        raise
    return _serve(config, Path(socket_path), first)


def _serve(config: DaemonConfig, socket_path: Path, first: dict) -> int:
    from softioc import asyncio_dispatcher, builder, softioc

    from cryod.ioc.access_security import AccessSecurityError, check_active

    with tempfile.TemporaryDirectory(prefix="cryod-ioc-") as folder:
        ioc = Ioc(config, socket_path, first, Path(folder))
        builder.LoadDatabase()
        dispatcher = asyncio_dispatcher.AsyncioDispatcher()
        softioc.iocInit(dispatcher)
        try:
            check_active(ioc.rules)
        except AccessSecurityError as error:
            print(f"cryod ioc: {error}", file=sys.stderr)
            softioc.safeEpicsExit(2)
        log.info("EPICS IOC of the daemon at %s: PVs %s*, %s", socket_path, config.ioc.prefix, ioc.rules_said)
        asyncio.run_coroutine_threadsafe(ioc.follow(), dispatcher.loop)
        dispatcher.wait_for_quit()
        log.info("EPICS IOC stopped")
    softioc.safeEpicsExit(0)
    return 0


__all__ = ["run", "Ioc", "IocError", "CONNECT_WAIT_S"]
