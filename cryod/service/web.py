"""The live web page (``web: {address, writable, token_file}``): the daemon as the lab watches it.

Off unless the configuration has a ``web`` section. The page (:mod:`cryod.service.web_assets`:
HTML, one script, one style sheet, plain canvas drawing, nothing fetched from elsewhere) reads:

* ``GET /api/status``: the status ``cryod ctl status --json`` gives, and whether the page may write;
* ``GET /api/history``: the last hour in one-second bins and the recent events
  (:mod:`cryod.service.history`);
* ``GET /api/events``: server-sent events, one every :data:`PUSH_S` while the loop runs: the
  status, the bins completed since and the new events, each frame with the sequence number of its
  last event as its ``id``. The stream's events start after ``?after=SEQ`` (the page gives the last
  of ``/api/history``) or the ``Last-Event-ID`` a browser sends when it reconnects, so an event
  folded in between is not lost; without either, after the newest;
* ``POST /api/command`` (only with ``web.writable: true``): ``{"command": "setpoint 5.2"}`` with the
  token of ``web.token_file`` in the ``X-Cryod-Token`` header. The command goes through the
  operator's command table and the loop's limits like every other path; the loop journals it with
  the peer's address (``by web page, 192.168.1.7:50122``). Only ``setpoint``, ``ramp``,
  ``heater-off`` and ``feedforward`` are taken from the page.

What a client can do to the interface is bounded: :data:`MAX_CLIENTS` connections at once (open
pages included; one more gets 503), a request head of at most :data:`MAX_HEAD_LINES` lines of
:data:`MAX_LINE` bytes within :data:`HEAD_TIMEOUT_S`, a body of at most :data:`MAX_BODY` bytes, one
request per connection, and a page that stops reading its events is closed. The history is folded
on this interface's thread; the loop only appends each row's reference to a deque.
"""

from __future__ import annotations

import asyncio
import json
import logging
import urllib.parse
from importlib import resources
from pathlib import Path
from typing import Callable

from cryod.service.commands import Command, parse_command
from cryod.service.control_socket import finite_or_none
from cryod.service.history import History, RecentRows
from cryod.service.async_clients import loop_answer
from cryod.service.tcp_service import TcpService, send
from cryod.web_token import read_token, token_matches

log = logging.getLogger("cryod.web")

#: Connections open at once (each open page holds one for its events).
MAX_CLIENTS = 32
#: Longest request line or header line, bytes.
MAX_LINE = 8192
#: Most header lines of a request.
MAX_HEAD_LINES = 64
#: How long a client has to send its request head (and a body), s.
HEAD_TIMEOUT_S = 5.0
#: Largest request body (a command), bytes.
MAX_BODY = 1024
#: Time between two pushes of the status to open pages, s (at least one a second).
PUSH_S = 0.5
#: A comment line is sent to an open page at least this often, s (proxies keep the stream open).
KEEPALIVE_S = 15.0
#: Commands the page may send.
PAGE_COMMANDS = ("setpoint", "ramp", "heater-off", "feedforward")
#: How long a write waits for the loop's answer, s.
REPLY_TIMEOUT_S = 5.0
#: The page's files (name: content type).
ASSETS = {"index.html": "text/html; charset=utf-8", "app.js": "text/javascript; charset=utf-8",
          "style.css": "text/css; charset=utf-8", "icon.svg": "image/svg+xml"}
#: Sent with every response: the page loads nothing from elsewhere and is not framed.
SECURITY_HEADERS = ("Content-Security-Policy: default-src 'none'; script-src 'self'; style-src 'self'; "
                    "connect-src 'self'; img-src 'self'; frame-ancestors 'none'; form-action 'none'\r\n"
                    "X-Content-Type-Options: nosniff\r\nReferrer-Policy: no-referrer\r\nCache-Control: no-store\r\n")
REASONS = {200: "OK", 400: "Bad Request", 403: "Forbidden", 404: "Not Found", 405: "Method Not Allowed",
           408: "Request Timeout", 411: "Length Required", 413: "Content Too Large",
           431: "Request Header Fields Too Large", 503: "Service Unavailable"}


def _events_after(query: str, headers: dict) -> int | None:
    """The sequence number an event stream starts after: the browser's ``Last-Event-ID`` on a reconnection,
    else the query's ``after``, else None; _HttpError naming the one that is not a whole number."""
    if "last-event-id" in headers:
        given, where = headers["last-event-id"], "Last-Event-ID"
    else:
        values = urllib.parse.parse_qs(query, keep_blank_values=True).get("after")
        if not values:
            return None
        given, where = values[-1], "after"
    if not (given.isascii() and given.isdigit() and len(given) <= 18):
        raise _HttpError(400, f"{where} must be a whole number of events, got {given[:40]!r}")
    return int(given)


class _HttpError(Exception):
    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code
        self.message = message


def load_assets() -> dict[str, bytes]:
    """The page's files, read once from the package."""
    folder = resources.files("cryod.service").joinpath("web_assets")
    return {name: folder.joinpath(name).read_bytes() for name in ASSETS}


class WebServer(TcpService):
    """Serves the live page from its own thread.

    Parameters
    ----------
    address : str
        ``host:port``.
    writable : bool
        ``web.writable``.
    token_file : pathlib.Path or None
        ``web.token_file`` (read at every write, so a new token takes effect at once).
    status : callable
        The daemon's status dict (as ``cryod ctl status --json`` gives it).
    submit : callable
        Hands a command to the loop.
    recent : RecentRows
        The row tap the loop feeds.
    line_amplitude_K : callable
        The cooler line's amplitude on T2 now (K).
    max_clients : int, optional
        Default :data:`MAX_CLIENTS`.
    """

    def __init__(self, address: str, writable: bool, token_file: Path | None, status: Callable[[], dict],
                 submit: Callable[[Command], Command], recent: RecentRows,
                 line_amplitude_K: Callable[[], float], max_clients: int | None = None):
        super().__init__("web page" + (" (writable)" if writable else " (read-only)"), address,
                         MAX_CLIENTS if max_clients is None else max_clients, stream_limit=MAX_LINE)
        self.writable = writable
        self.token_file = token_file
        self.status = status
        self.submit = submit
        self.recent = recent
        self.line_amplitude_K = line_amplitude_K
        self.history = History()
        self.assets = load_assets()
        #: Open pages (event streams) now, and the requests served since the start.
        self.pages = 0
        self.requests = 0
        self._frame: dict | None = None
        self._new_frame: asyncio.Event | None = None

    # -- the history and the frames pushed to open pages ----------------------------------
    async def background(self) -> None:
        if self._new_frame is None:
            self._new_frame = asyncio.Event()
        while True:
            self.history.take(self.recent, self.line_amplitude_K)
            if self.pages:
                status = self.status()
                if self._frame is None or status.get("time_s") != self._frame["status"].get("time_s"):
                    self._frame = {"status": finite_or_none(status)}
                    self._new_frame.set()
                    self._new_frame = asyncio.Event()
            await asyncio.sleep(PUSH_S)

    # -- one client -----------------------------------------------------------------------
    async def busy(self, writer: asyncio.StreamWriter) -> None:
        await self._respond(writer, 503, {"message": f"busy: {self.clients} connections open (at most "
                                                     f"{self.max_clients}); try again in a moment"})

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, peer: str) -> None:
        self.requests += 1
        try:
            method, target, headers = await asyncio.wait_for(self._head(reader), HEAD_TIMEOUT_S)
            path, _, query = target.partition("?")
            if path == "/api/events" and method == "GET":
                await self._events(writer, _events_after(query, headers))
            elif method == "GET":
                await self._get(writer, path)
            elif method == "POST" and path == "/api/command":
                await self._command(reader, writer, headers, peer)
            else:
                raise _HttpError(405 if path in ("/", "/api/command", "/api/status", "/api/history") else 404,
                                 f"{method} {path[:80]} is not served here")
        except _HttpError as error:
            await self._respond(writer, error.code, {"message": error.message})
        except asyncio.TimeoutError:
            await self._respond(writer, 408, {"message": f"no complete request within {HEAD_TIMEOUT_S:g} s"})

    async def _head(self, reader: asyncio.StreamReader) -> tuple[str, str, dict[str, str]]:
        """Method, target (path and query) and headers (lower-case names) of the request; _HttpError when
        malformed."""
        lines = []
        while True:
            try:
                line = await reader.readuntil(b"\n")
            except asyncio.LimitOverrunError:
                raise _HttpError(431, f"a request line longer than {MAX_LINE} bytes") from None
            except asyncio.IncompleteReadError:
                raise _HttpError(400, "the request ended before its head did") from None
            line = line.rstrip(b"\r\n")
            if not line:
                break
            lines.append(line)
            if len(lines) > MAX_HEAD_LINES:
                raise _HttpError(431, f"more than {MAX_HEAD_LINES} header lines")
        try:
            method, target, version = lines[0].decode("ascii").split(" ")
            headers = {}
            for line in lines[1:]:
                name, separator, value = line.decode("latin-1").partition(":")
                if not separator:
                    raise ValueError(line)
                headers[name.strip().lower()] = value.strip()
        except (IndexError, ValueError, UnicodeDecodeError):
            raise _HttpError(400, "not an HTTP request") from None
        if not version.startswith("HTTP/1.") or not target.startswith("/"):
            raise _HttpError(400, "not an HTTP/1 request")
        return method, target, headers

    async def _get(self, writer: asyncio.StreamWriter, path: str) -> None:
        if path == "/api/status":
            await self._respond(writer, 200, {"status": finite_or_none(self.status()), "writable": self.writable,
                                              "page_commands": list(PAGE_COMMANDS) if self.writable else []})
            return
        if path == "/api/history":
            await self._respond(writer, 200, {"bins": list(self.history.bins), "events": list(self.history.events)})
            return
        name = "index.html" if path == "/" else path.removeprefix("/")
        if name not in self.assets:
            raise _HttpError(404, f"{path[:80]} is not served here")
        await self._send(writer, 200, self.assets[name], ASSETS[name])

    async def _events(self, writer: asyncio.StreamWriter, after: int | None) -> None:
        """Server-sent events: the status at every new frame, with the bins and events since the last.

        The events start after sequence number ``after`` (None, or one this history has not reached, as after
        a restart of the daemon: after the newest). Where the stream starts is taken before its headers go out:
        the page counts as connected once it has them."""
        last_bin = self.history.bins[-1]["time_s"] if self.history.bins else None
        newest = self.history.events[-1]["seq"] if self.history.events else 0
        last_event = newest if after is None or after > newest else after
        await send(writer, ("HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nConnection: close\r\n"
                            + SECURITY_HEADERS + "\r\n").encode("ascii"))
        self.pages += 1
        if self._new_frame is None:
            self._new_frame = asyncio.Event()
        try:
            while True:
                waiting = self._new_frame
                try:
                    await asyncio.wait_for(waiting.wait(), KEEPALIVE_S)
                except asyncio.TimeoutError:
                    await send(writer, b": still here\n\n")
                    continue
                bins = self.history.since(last_bin)
                events = [event for event in self.history.events if event["seq"] > last_event]
                last_bin = bins[-1]["time_s"] if bins else last_bin
                last_event = events[-1]["seq"] if events else last_event
                frame = dict(self._frame, bins=bins, events=events)
                await send(writer, f"id: {last_event}\n".encode("ascii") + b"data: "
                           + json.dumps(frame).encode("utf-8") + b"\n\n")
        finally:
            self.pages -= 1

    async def _command(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, headers: dict,
                       peer: str) -> None:
        sender = f"web page, {peer}"
        if not self.writable:
            log.warning("web page: a command refused: web.writable is false (by %s)", sender)
            raise _HttpError(403, "this page is read-only (web.writable: false)")
        origin = headers.get("origin")
        if origin is not None and origin.split("://", 1)[-1] != headers.get("host"):
            log.warning("web page: a command from another site's page refused (origin %s; by %s)", origin[:80],
                        sender)
            raise _HttpError(403, "a command from another site's page is refused")
        try:
            token = read_token(self.token_file)
        except (TypeError, ValueError) as error:
            log.error("web page: commands refused: web.token_file: %s", error)
            raise _HttpError(503, "commands are refused: the daemon cannot read its token file") from None
        if not token_matches(headers.get("x-cryod-token"), token):
            log.warning("web page: a command refused: wrong or missing token (by %s)", sender)
            raise _HttpError(403, "wrong or missing token (X-Cryod-Token)")
        length = headers.get("content-length", "")
        if not length.isdigit():
            raise _HttpError(411, "a command needs Content-Length")
        if int(length) > MAX_BODY:
            raise _HttpError(413, f"a command is at most {MAX_BODY} bytes")
        try:
            body = await asyncio.wait_for(reader.readexactly(int(length)), HEAD_TIMEOUT_S)
            line = json.loads(body.decode("utf-8"))["command"]
            if not isinstance(line, str):
                raise TypeError(line)
            command = parse_command(line)
        except (ValueError, KeyError, TypeError, UnicodeDecodeError) as error:
            message = str(error) if isinstance(error, ValueError) and not isinstance(error, json.JSONDecodeError) \
                else 'send {"command": "setpoint 5.2"}'
            log.warning("web page: a command refused: %s (by %s)", message, sender)
            await self._respond(writer, 400, {"ok": False, "message": message})
            return
        if command.name not in PAGE_COMMANDS:
            log.warning("web page: %s refused: not taken from the page (by %s)", command.name, sender)
            await self._respond(writer, 400, {"ok": False, "message": f"{command.name} is not taken from the page; "
                                                                      f"commands: {', '.join(PAGE_COMMANDS)}"})
            return
        command.sender = sender
        answered = await loop_answer(command, self.submit, REPLY_TIMEOUT_S)
        await self._respond(writer, 200, {"ok": answered.ok, "message": answered.message,
                                          "status": finite_or_none(self.status())})

    # -- responses --------------------------------------------------------------------------
    async def _respond(self, writer: asyncio.StreamWriter, code: int, content: dict) -> None:
        await self._send(writer, code, json.dumps(content).encode("utf-8"), "application/json")

    async def _send(self, writer: asyncio.StreamWriter, code: int, body: bytes, content_type: str) -> None:
        head = (f"HTTP/1.1 {code} {REASONS.get(code, 'Error')}\r\nContent-Type: {content_type}\r\n"
                f"Content-Length: {len(body)}\r\nConnection: close\r\n" + SECURITY_HEADERS + "\r\n")
        try:
            await send(writer, head.encode("ascii") + body)
        except (ConnectionError, asyncio.TimeoutError):
            pass
