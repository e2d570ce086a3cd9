"""The interfaces process's run: its servers on one event loop, its link to the daemon, its hooks, its end.

:func:`main` reads the :class:`~cryod.service.interfaces_process.InterfaceSettings` the daemon writes on
standard input, starts what they configure (the web page, the 336 command set, the metrics endpoint,
the alarm hooks), subscribes to the daemon's stream and serves until standard input closes (the
daemon stopped) or SIGTERM comes. A server that cannot listen is said in the journal and in the
report the daemon shows in its status; the others run all the same. New settings after a reload
change what may change without a restart: the alarm hook and the 336's view of the configuration.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import signal
import sys
import threading

from cryod.alarms.latch import Transition
from cryod.interfaces.daemon_link import DaemonLink
from cryod.interfaces.lakeshore336_server import Lakeshore336Server
from cryod.interfaces.metrics import MetricsEndpoint
from cryod.interfaces.mirror import DaemonMirror
from cryod.interfaces.web import WebPage
from cryod.service.alarm_hook import AlarmHookRunner
from cryod.service.interfaces_process import InterfaceSettings, read_settings
from cryod.service.logs import ServiceLogging
from cryod.thread_priority import at_normal_priority

log = logging.getLogger("cryod.interfaces")


class DaemonClock:
    """The daemon's clock as its stream tells it (the time of its latest row), for the hooks' intervals."""

    def __init__(self, mirror: DaemonMirror):
        self.mirror = mirror

    def now(self) -> float:
        time_s = self.mirror.time_s
        return 0.0 if time_s != time_s else time_s


class Interfaces:
    """What one interfaces process serves.

    Parameters
    ----------
    settings : InterfaceSettings
    after : int, optional
        The last event the process before this one took (its hooks then act on what followed).
    """

    def __init__(self, settings: InterfaceSettings, after: int | None = None):
        self.settings = settings
        self.mirror = DaemonMirror(settings.period_s, settings.cooler_rad_s)
        self.link = DaemonLink(settings.socket_path, self.mirror, self.report, after)
        self.problems: list[str] = []
        self.web: WebPage | None = None
        self.lakeshore336: Lakeshore336Server | None = None
        self.metrics: MetricsEndpoint | None = None
        self.hooks = AlarmHookRunner(DaemonClock(self.mirror), settings.cryostat, settings.alarm_hook)
        self.mirror.on_event(self._offer_to_hooks)

    def _offer_to_hooks(self, event: dict) -> None:
        details = event.get("alarm")
        if event["kind"] == "alarm" and isinstance(details, dict):
            try:
                self.hooks.offer(Transition(**details))
            except TypeError as error:
                log.warning("an alarm change the hook cannot take: %s", error)

    def report(self) -> dict:
        """What this process says of itself to the daemon (shown in its status as ``interfaces``)."""
        def where(server) -> str | None:
            return None if server is None else f"{server.host}:{server.port}"

        return {"pid": os.getpid(),
                "web": None if self.web is None else f"http://{where(self.web.server)}/",
                "lakeshore336": where(self.lakeshore336),
                "metrics": None if self.metrics is None else f"http://{where(self.metrics.server)}/metrics",
                "alarm_hook": self.hooks.status() if self.settings.alarm_hook is not None else None,
                "problems": list(self.problems) + ([self.hooks.problem] if self.hooks.problem else [])}

    async def start(self) -> None:
        """Start what the settings configure; one that cannot listen is said and left out."""
        settings = self.settings
        if settings.web is not None:
            self.web = await self._started(WebPage(settings.web, self.mirror, self.link, settings.heater_max_w))
        if settings.lakeshore336 is not None:
            self.lakeshore336 = await self._started(
                Lakeshore336Server(settings.lakeshore336, lambda: self.settings.lakeshore336_setup, self.mirror,
                                   self.link, settings.socket_path))
        if settings.metrics_address is not None:
            def alarms() -> dict[str, float]:
                return dict(self.mirror.stream_status.alarm_states)

            self.metrics = await self._started(MetricsEndpoint(self.mirror.view, settings.metrics_address,
                                                               settings.cryostat, alarms))
        self.hooks.start()

    async def _started(self, interface):
        try:
            await interface.start()
        except OSError as error:
            problem = f"not started: {error}"
            log.error("%s", problem)
            self.problems.append(problem)
            return None
        return interface

    def configure(self, settings: InterfaceSettings) -> None:
        """New settings after a reload: the alarm hook and the 336's view of the configuration."""
        self.settings = settings
        self.hooks.configure(settings.alarm_hook)

    async def stop(self) -> None:
        for interface in (self.web, self.lakeshore336, self.metrics):
            if interface is not None:
                await interface.stop()
        self.hooks.stop()


async def serve(settings: InterfaceSettings, after: int | None, settings_pipe) -> int:
    """Serve until the settings pipe closes or SIGTERM comes."""
    interfaces = Interfaces(settings, after)
    event_loop = asyncio.get_running_loop()
    ended = asyncio.Event()
    event_loop.add_signal_handler(signal.SIGTERM, ended.set)

    def read_more() -> None:                    # on a thread of its own: the pipe blocks
        while True:
            try:
                more = read_settings(settings_pipe)
            except (OSError, ValueError) as error:
                log.error("the daemon's settings could not be read: %s", error)
                more = None
            if more is None:
                event_loop.call_soon_threadsafe(ended.set)
                return
            event_loop.call_soon_threadsafe(interfaces.configure, more)

    await interfaces.start()
    threading.Thread(target=read_more, name="cryod-interfaces-settings", daemon=True).start()
    link = asyncio.ensure_future(interfaces.link.run())
    await ended.wait()
    link.cancel()
    await interfaces.stop()
    return 0


def main(argv: list[str]) -> int:
    """``python -m cryod.interfaces [--after SEQ]``: read the settings from standard input and serve."""
    parser = argparse.ArgumentParser(prog="python -m cryod.interfaces",
                                     description="cryod's interfaces process (started by the daemon)")
    parser.add_argument("--after", type=int, default=None, help="the last event a process before this one took")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # a terminal's Ctrl-C stops the daemon, which ends this
    at_normal_priority()
    logging_ = ServiceLogging()
    logging_.start()
    try:
        pipe = sys.stdin.buffer
        settings = read_settings(pipe)
        if settings is None:
            log.error("no settings on standard input: this process is started by the cryod daemon")
            return 2
        return asyncio.run(serve(settings, args.after, pipe))
    finally:
        logging_.stop()


__all__ = ["Interfaces", "main", "serve"]
