"""The live web page (``web: {address, writable, token_file, allowed_hosts}``): the daemon as the lab watches it.

Off unless the configuration has a ``web`` section; served by the interfaces process
(:mod:`cryod.interfaces`), never by the daemon's. The page (``web_assets``: HTML, one script, one
style sheet, and the uPlot charting library 1.6.32 (MIT), vendored from the npm registry with its
licence; nothing fetched from elsewhere) reads:

* ``GET /api/status``: the status ``cryod ctl status --json`` gives, whether the page may write, and
  ``clock_offset_s``, the wall clock at the daemon's clock time 0 (a ``time_s`` plus this is the time
  of day the record gives it);
* ``GET /api/history``: the last hour in one-second bins and the recent events
  (:mod:`cryod.interfaces.history`), folded and encoded in this process, and ``clock_offset_s``;
* ``GET /api/events``: server-sent events, one every :data:`PUSH_S` while the loop runs: the status,
  the bins completed since and the new events, each frame with the sequence number of its last event
  as its ``id``. The stream's events start after ``?after=SEQ`` (the page gives the last of
  ``/api/history``) or the ``Last-Event-ID`` a browser sends when it reconnects, so an event folded
  in between is not lost; without either, after the newest;
* ``POST /api/command`` (only with ``web.writable: true``): ``{"command": "setpoint 5.2"}`` with the
  token of ``web.token_file`` in the ``X-Cryod-Token`` header. The command goes to the daemon through
  its control socket, through the operator's command table and the loop's limits like every other
  path; the loop journals it with the page's client (``by web page, 192.168.1.7:50122``, and the
  user for a client on this computer). Only ``setpoint``, ``ramp``, ``heater-off`` and
  ``feedforward`` are taken from the page. A command the daemon refuses is answered 409 with its
  reason, one it could not be asked 503; anything else the page may not do is a 4xx with the reason.

What a client can do to the server is bounded by :class:`~cryod.interfaces.http_server.HttpServer`:
connections, heads, bodies, the ``Host`` it names, event streams that are not read.
"""

from __future__ import annotations

import asyncio
import json
import logging
import socket
from importlib import resources
from typing import AsyncIterator

from cryod.config import WebConfig
from cryod.interfaces.daemon_link import DaemonLink
from cryod.interfaces.http_server import EventStream, HttpServer, Request, Response
from cryod.interfaces.mirror import DaemonMirror
from cryod.interfaces.peers import is_loopback, loopback_peer, user_name
from cryod.listen_address import parse_address
from cryod.service.commands import parse_command
from cryod.service.daemon_status import status_json
from cryod.service.stream import finite_or_none
from cryod.web_token import read_token, token_matches

log = logging.getLogger("cryod.web")

#: Connections open at once (each open page holds one for its events).
MAX_CLIENTS = 64
#: Event streams (open pages) among them.
MAX_PAGES = 32
#: Largest request body (a command), bytes.
MAX_BODY = 1024
#: Time between two pushes of the status to open pages, s (at least one a second).
PUSH_S = 0.5
#: A comment line is sent to an open page at least this often, s (proxies keep the stream open).
KEEPALIVE_S = 15.0
#: Commands the page may send.
PAGE_COMMANDS = ("setpoint", "ramp", "heater-off", "feedforward")
#: The page's files (name: content type).
ASSETS = {"index.html": "text/html; charset=utf-8", "app.js": "text/javascript; charset=utf-8",
          "style.css": "text/css; charset=utf-8", "icon.svg": "image/svg+xml",
          "uPlot.iife.min.js": "text/javascript; charset=utf-8", "uPlot.min.css": "text/css; charset=utf-8",
          "uPlot.LICENSE.txt": "text/plain; charset=utf-8"}


def load_assets() -> dict[str, bytes]:
    """The page's files, read once from the package."""
    folder = resources.files("cryod.interfaces").joinpath("web_assets")
    return {name: folder.joinpath(name).read_bytes() for name in ASSETS}


def allowed_hosts(config: WebConfig) -> set[str]:
    """The names the ``Host`` header may give: the listening address, this computer's loopback names, its host
    names, and ``web.allowed_hosts``; for an address that listens on all interfaces, this computer's addresses."""
    host, _ = parse_address(config.address, allow_any_port=True)
    names = {host.lower(), "localhost", "127.0.0.1", "::1"}
    for name in (socket.gethostname(), socket.getfqdn()):
        names.add(name.lower())
        try:
            names.update(str(info[4][0]) for info in socket.getaddrinfo(name, None))
        except OSError:
            pass
    names.update(name.lower() for name in config.allowed_hosts)
    return names


def json_response(status: int, content: dict) -> Response:
    return Response(status, json.dumps(finite_or_none(content)).encode("utf-8"), "application/json")


def error_body(status: int, message: str) -> tuple[bytes, str]:
    return json.dumps({"ok": False, "message": message}).encode("utf-8"), "application/json"


class _Refusal(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


def events_after(request: Request) -> int | None:
    """The sequence number an event stream starts after: the browser's ``Last-Event-ID`` on a reconnection, else
    the query's ``after``, else None; a refusal naming the one that is not a whole number."""
    if "last-event-id" in request.headers:
        given, where = request.headers["last-event-id"], "Last-Event-ID"
    else:
        values = request.query.get("after")
        if not values:
            return None
        given, where = values[-1], "after"
    if not (given.isascii() and given.isdigit() and len(given) <= 18):
        raise _Refusal(400, f"{where} must be a whole number of events, got {given[:40]!r}")
    return int(given)


def client_words(request: Request) -> str:
    """Who sent a request, for the journal: its address and, on this computer, its user."""
    peer = loopback_peer(request.peer[:2], request.server[:2]) if is_loopback(request.peer[0]) else None
    if peer is None:
        return request.peer_text
    return f"{request.peer_text}, uid {peer.uid} ({user_name(peer.uid)})"


class WebPage:
    """The page's routes on an :class:`HttpServer`.

    Parameters
    ----------
    config : WebConfig
    mirror : DaemonMirror
    link : DaemonLink
        Commands go through it.
    heater_max_w : float
        R * I_max^2 (W), the top of the heater chart (``heater_max_W`` of ``/api/status``).
    """

    def __init__(self, config: WebConfig, mirror: DaemonMirror, link: DaemonLink, heater_max_w: float):
        self.config = config
        self.heater_max_w = heater_max_w
        self.mirror = mirror
        self.link = link
        self.assets = load_assets()
        self.server = HttpServer("web page" + (" (writable)" if config.writable else " (read-only)"), config.address,
                                 self.route, MAX_CLIENTS, MAX_PAGES, allowed_hosts(config), MAX_BODY, error_body)

    @property
    def writable(self) -> bool:
        return self.config.writable

    @property
    def clock_offset_s(self) -> float:
        """The wall clock at the daemon's clock time 0 (s since the epoch): a time of the status or of a bin plus
        this is the time of day the record gives it."""
        return float(self.mirror.hello.get("clock_offset_s") or 0.0)

    async def start(self) -> None:
        await self.server.start()

    async def stop(self) -> None:
        await self.server.stop()

    async def route(self, request: Request) -> Response | EventStream:
        try:
            if request.method == "GET":
                return await self._get(request)
            if request.method == "POST" and request.path == "/api/command":
                return await self._command(request)
            status = 405 if request.path in ("/", "/api/command", "/api/status", "/api/history", "/api/events") \
                else 404
            raise _Refusal(status, f"{request.method} {request.path[:80]} is not served here")
        except _Refusal as refusal:
            return json_response(refusal.status, {"ok": False, "message": refusal.message})

    async def _get(self, request: Request) -> Response | EventStream:
        path = request.path
        if path == "/api/status":
            return json_response(200, {"status": status_json(self.mirror.status()), "writable": self.writable,
                                       "page_commands": list(PAGE_COMMANDS) if self.writable else [],
                                       "clock_offset_s": self.clock_offset_s, "heater_max_W": self.heater_max_w})
        if path == "/api/history":
            history = self.mirror.history
            return json_response(200, {"bins": list(history.bins), "events": list(history.events),
                                       "clock_offset_s": self.clock_offset_s})
        if path == "/api/events":
            after = events_after(request)           # refused before the stream's head goes out
            return EventStream(lambda: self._frames(after))
        name = "index.html" if path == "/" else path.removeprefix("/")
        if name not in self.assets:
            raise _Refusal(404, f"{path[:80]} is not served here")
        return Response(200, self.assets[name], ASSETS[name])

    async def _frames(self, after: int | None) -> AsyncIterator[bytes]:
        """Server-sent events: the status at every new tick, with the bins and events since the last frame.

        The events start after sequence number ``after`` (None, or one this history has not reached, as after
        a restart of the daemon: after the newest); where the stream starts is taken before its headers go out."""
        history = self.mirror.history
        last_bin = history.bins[-1]["time_s"] if history.bins else None
        newest = history.events[-1]["seq"] if history.events else 0
        last_event = newest if after is None or after > newest else after
        last_time = None
        while True:
            try:
                await asyncio.wait_for(self._next_tick(last_time), KEEPALIVE_S)
            except asyncio.TimeoutError:
                yield b": still here\n\n"
                continue
            status = self.mirror.status()
            last_time = status.loop.time_s
            bins = history.since(last_bin)
            events = [event for event in history.events if event["seq"] > last_event]
            last_bin = bins[-1]["time_s"] if bins else last_bin
            last_event = events[-1]["seq"] if events else last_event
            frame = json.dumps(finite_or_none({"status": status_json(status), "bins": bins, "events": events}))
            yield f"id: {last_event}\ndata: {frame}\n\n".encode("utf-8")
            await asyncio.sleep(PUSH_S)

    async def _next_tick(self, last_time: float | None) -> None:
        """Until the mirror holds a status of another tick than ``last_time``."""
        while last_time is not None and self.mirror.stream_status.loop.time_s == last_time:
            await self.mirror.changed.wait()

    async def _command(self, request: Request) -> Response:
        sender = f"web page, {client_words(request)}"
        if not self.writable:
            log.warning("web page: a command refused: web.writable is false (by %s)", sender)
            raise _Refusal(403, "this page is read-only (web.writable: false)")
        origin = request.headers.get("origin")
        if origin is not None and origin.split("://", 1)[-1] != request.headers.get("host"):
            log.warning("web page: a command from another site's page refused (origin %s; by %s)", origin[:80],
                        sender)
            raise _Refusal(403, "a command from another site's page is refused")
        try:
            if self.config.token_file is None:  # the configuration refuses a writable page without one
                raise ValueError("no web.token_file")
            token = read_token(self.config.token_file)
        except (TypeError, ValueError) as error:
            log.error("web page: commands refused: web.token_file: %s", error)
            raise _Refusal(503, "commands are refused: the daemon cannot read its token file") from None
        if not token_matches(request.headers.get("x-cryod-token"), token):
            log.warning("web page: a command refused: wrong or missing token (by %s)", sender)
            raise _Refusal(403, "wrong or missing token (X-Cryod-Token)")
        try:
            line = json.loads(request.body.decode("utf-8"))["command"]
            if not isinstance(line, str):
                raise TypeError(line)
            command = parse_command(line)
        except (ValueError, KeyError, TypeError, UnicodeDecodeError) as error:
            message = str(error) if isinstance(error, ValueError) and not isinstance(error, json.JSONDecodeError) \
                else 'send {"command": "setpoint 5.2"}'
            log.warning("web page: a command refused: %s (by %s)", message, sender)
            raise _Refusal(400, message) from None
        if command.name not in PAGE_COMMANDS:
            log.warning("web page: %s refused: not taken from the page (by %s)", command.name, sender)
            raise _Refusal(400, f"{command.name} is not taken from the page; commands: {', '.join(PAGE_COMMANDS)}")
        reply = await self.link.command(line.strip(), sender)
        status = 200 if reply.get("ok") else (409 if "status" in reply else 503)
        return json_response(status, {"ok": bool(reply.get("ok")), "message": reply.get("message", ""),
                                      "status": reply.get("status") or status_json(self.mirror.status())})


__all__ = ["WebPage", "PAGE_COMMANDS", "allowed_hosts", "load_assets"]
