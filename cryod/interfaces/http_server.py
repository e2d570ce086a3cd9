"""An HTTP/1.1 server no client can lock out: h11 speaks HTTP, this module keeps the door.

The web page and the metrics endpoint are served by :class:`HttpServer` on the interfaces
process's event loop. The protocol (request heads, bodies, chunked responses, errors) is the h11
library's; what is kept here is who gets a place:

* at most ``max_connections`` open at once. When one more arrives, a place is made: the connection
  that has waited longest without a complete request head is closed (a slow or idle client has had
  its chance: a browser sends its head as it connects); failing that, the event stream whose client
  has read least; failing that, the newcomer gets 503;
* a request head within :data:`HEAD_TIMEOUT_S` of connecting and of at most :data:`MAX_HEAD_BYTES`,
  a body of at most ``max_body`` bytes within the same time; one request per connection;
* at most ``max_streams`` event streams at once; one more takes the place of the stream whose client
  has read least, or the oldest;
* an event stream whose client reads nothing for :data:`STREAM_STALL_S` is closed: for a client on
  this computer the kernel's socket table says what it has received and not read
  (:func:`cryod.interfaces.peers.loopback_peer`), for one elsewhere what it has not acknowledged;
* the ``Host`` header must name this server (``allowed_hosts``): a page of another site that a DNS
  rebinding points at this address is refused (421).

A route is ``async route(request) -> Response | EventStream``.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time
import urllib.parse
from dataclasses import dataclass
from typing import AsyncIterator, Awaitable, Callable

import h11

from cryod.interfaces.peers import loopback_peer, unsent_bytes
from cryod.listen_address import describe, is_loopback, parse_address

log = logging.getLogger("cryod.http")

#: How long a client has to send its request head (and its body), s.
HEAD_TIMEOUT_S = 5.0
#: Longest request head, bytes.
MAX_HEAD_BYTES = 8192
#: An event stream whose client reads nothing for this long is closed, s.
STREAM_STALL_S = 3.0
#: How often the open connections are looked at (head timeouts, stalled streams), s.
SWEEP_S = 0.5
#: How long a response may wait for a client that does not take it, s.
SEND_TIMEOUT_S = 5.0
#: Sent with every response: nothing is loaded from elsewhere and the page is not framed.
SECURITY_HEADERS = (
    ("Content-Security-Policy", "default-src 'none'; script-src 'self'; style-src 'self'; connect-src 'self'; "
                                "img-src 'self'; frame-ancestors 'none'; form-action 'none'"),
    ("X-Content-Type-Options", "nosniff"), ("Referrer-Policy", "no-referrer"), ("Cache-Control", "no-store"))


@dataclass
class Request:
    """One request: method, path, query values, headers (lower-case names), body, the client's address."""

    method: str
    path: str
    query: dict[str, list[str]]
    headers: dict[str, str]
    body: bytes
    peer: tuple[str, int]
    server: tuple[str, int]

    @property
    def peer_text(self) -> str:
        host, port = self.peer[:2]
        return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


@dataclass
class Response:
    """A whole response."""

    status: int
    body: bytes = b""
    content_type: str = "application/json"
    headers: tuple[tuple[str, str], ...] = ()


@dataclass
class EventStream:
    """A response that goes on: ``frames()`` yields what to send, each already in the event-stream format."""

    frames: Callable[[], AsyncIterator[bytes]]
    headers: tuple[tuple[str, str], ...] = ()


class _Place:
    """What the server knows of one open connection."""

    HEAD, BUSY, STREAM = "waiting for its request", "being answered", "streaming"

    def __init__(self, task: asyncio.Task, writer: asyncio.StreamWriter):
        self.task = task
        self.writer = writer
        self.state = self.HEAD
        self.opened = time.monotonic()
        self.unread_since: float | None = None
        self.unread_bytes = 0
        self.closed_why: str | None = None

    def close(self, why: str) -> None:
        self.closed_why = why
        self.writer.transport.abort()
        self.task.cancel()


class _Refused(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


class HttpServer:
    """Serves ``route`` on ``address``.

    Parameters
    ----------
    what : str
        Its name in the journal (``web page``).
    address : str
        ``host:port`` (port 0: any free port, see :attr:`port`).
    route : callable
        ``await route(request)``: a :class:`Response` or an :class:`EventStream`.
    max_connections, max_streams : int
        Connections open at once; event streams among them.
    allowed_hosts : set of str or None
        The names the ``Host`` header may give (without the port); None: any.
    max_body : int
        Largest request body, bytes.
    error_body : callable
        ``error_body(status, message) -> (bytes, content type)`` for refusals.
    """

    def __init__(self, what: str, address: str, route: Callable[[Request], Awaitable[Response | EventStream]],
                 max_connections: int, max_streams: int = 0, allowed_hosts: set[str] | None = None,
                 max_body: int = 1024, error_body: Callable[[int, str], tuple[bytes, str]] | None = None):
        self.what = what
        self.host, self.port = parse_address(address, allow_any_port=True, host_names=True)
        self.route = route
        self.max_connections = max_connections
        self.max_streams = max_streams
        self.allowed_hosts = allowed_hosts
        self.max_body = max_body
        self.error_body = error_body or (lambda status, message: (message.encode("utf-8") + b"\n", "text/plain"))
        self.places: dict[asyncio.Task, _Place] = {}
        #: Counts for the status and tests: requests, refusals as busy, connections closed for room, streams
        #: closed for not reading, heads not sent in time.
        self.counts = {"requests": 0, "busy": 0, "closed_for_room": 0, "closed_not_reading": 0, "head_timeouts": 0}
        self._server: asyncio.AbstractServer | None = None
        self._sweeper: asyncio.Task | None = None

    # -- running ----------------------------------------------------------------------------
    async def start(self) -> None:
        """Listen (an address in use or not on this host raises OSError naming it) and serve."""
        try:
            family = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_STREAM)[0][0]
            listener = socket.socket(family, socket.SOCK_STREAM)
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                listener.bind((self.host, self.port))
                listener.listen(128)
            except OSError:
                listener.close()
                raise
        except OSError as error:
            raise OSError(f"{self.what} on {self.host}:{self.port}: {error.strerror or error}") from error
        listener.setblocking(False)
        self.port = listener.getsockname()[1]
        self._server = await asyncio.start_server(self._client, sock=listener, limit=MAX_HEAD_BYTES)
        self._sweeper = asyncio.ensure_future(self._sweep())
        try:
            local = is_loopback(self.host)
            line = describe(self.what, self.host, self.port)
        except ValueError:                      # a host name (metrics.address may give one)
            local, line = False, f"{self.what} on {self.host}:{self.port}"
        log.log(logging.INFO if local else logging.WARNING, "%s", line)

    async def stop(self) -> None:
        if self._sweeper is not None:
            self._sweeper.cancel()
        if self._server is not None:
            self._server.close()
        for place in list(self.places.values()):
            place.close("the interfaces process is stopping")

    @property
    def streams(self) -> int:
        return sum(place.state == _Place.STREAM for place in self.places.values())

    # -- places -------------------------------------------------------------------------------
    def _make_room(self) -> bool:
        """A place for one more connection, by closing the one most deserving; False when none may be closed."""
        if len(self.places) < self.max_connections:
            return True
        waiting = [place for place in self.places.values() if place.state == _Place.HEAD]
        if waiting:
            victim = min(waiting, key=lambda place: place.opened)
        else:
            streams = [place for place in self.places.values() if place.state == _Place.STREAM]
            if not streams:
                return False
            victim = max(streams, key=lambda place: (place.unread_bytes, -place.opened))
        self.counts["closed_for_room"] += 1
        victim.close("closed to make room")
        self.places.pop(victim.task, None)
        return True

    async def _sweep(self) -> None:
        """Close the event streams whose client reads nothing."""
        while True:
            await asyncio.sleep(SWEEP_S)
            now = time.monotonic()
            for place in list(self.places.values()):
                if place.state == _Place.STREAM:
                    try:
                        self._look_at_stream(place, now)
                    except Exception as error:      # one stream's trouble never stops the looks at the others
                        log.warning("%s: looking at an event stream failed: %s: %s", self.what,
                                    type(error).__name__, error)

    def _look_at_stream(self, place: _Place, now: float) -> None:
        transport = place.writer.transport
        connection = transport.get_extra_info("socket")
        peer, here = transport.get_extra_info("peername"), transport.get_extra_info("sockname")
        unread = transport.get_write_buffer_size()
        peer_socket = loopback_peer(peer[:2], here[:2]) if peer and here else None
        if peer_socket is not None:
            unread += peer_socket.unread_bytes
        elif connection is not None:
            unread += unsent_bytes(connection)
        place.unread_bytes = unread
        if unread == 0:
            place.unread_since = None
            return
        if place.unread_since is None:
            place.unread_since = now
        elif now - place.unread_since > STREAM_STALL_S:
            self.counts["closed_not_reading"] += 1
            log.info("%s: an event stream to %s closed: its client read nothing for %.0f s (%d bytes waiting)",
                     self.what, peer, now - place.unread_since, unread)
            place.close("not reading")

    # -- one client ---------------------------------------------------------------------------
    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None                 # a client is served in a task of its own
        if not self._make_room():
            self.counts["busy"] += 1
            await self._raw_refusal(writer, 503, f"busy: {len(self.places)} connections are being answered; "
                                                 f"try again in a moment")
            return
        place = self.places[task] = _Place(task, writer)
        connection = h11.Connection(h11.SERVER, max_incomplete_event_size=MAX_HEAD_BYTES)
        try:
            request = await asyncio.wait_for(self._request(reader, writer, connection, place), HEAD_TIMEOUT_S)
            self.counts["requests"] += 1
            place.state = _Place.BUSY
            try:
                self._check_host(request)
                answer = await self.route(request)
            except _Refused as refused:
                answer = self._refusal(refused.status, refused.message)
            if isinstance(answer, EventStream):
                await self._stream(writer, connection, place, answer)
            else:
                await self._respond(writer, connection, answer)
        except _Refused as refused:
            await self._respond(writer, connection, self._refusal(refused.status, refused.message))
        except asyncio.TimeoutError:
            if place.state in (_Place.HEAD, _Place.BUSY):
                self.counts["head_timeouts"] += 1
                await self._raw_refusal(writer, 408, f"no complete request within {HEAD_TIMEOUT_S:g} s")
        except h11.RemoteProtocolError as error:
            await self._respond(writer, connection, self._refusal(error.error_status_hint, f"not a request "
                                                                                           f"taken here: {error}"))
        except (asyncio.CancelledError, ConnectionError, h11.LocalProtocolError):
            pass                                # closed for room, not reading, stopping; a client gone
        except Exception as error:              # one client's trouble never ends the server
            log.warning("%s: a client's request failed: %s: %s", self.what, type(error).__name__, error)
        finally:
            self.places.pop(task, None)
            if place.closed_why:
                writer.transport.abort()
            else:
                writer.close()

    async def _request(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                       connection: h11.Connection, place: _Place) -> Request:
        head: h11.Request | None = None
        body = bytearray()
        while True:
            event = connection.next_event()
            if event is h11.NEED_DATA:
                data = await reader.read(4096)
                connection.receive_data(data)
                if not data and connection.their_state is not h11.DONE:
                    raise ConnectionError("the client closed before its request ended")
                continue
            if isinstance(event, h11.Request):
                head = event
                place.state = _Place.BUSY
                length = dict(event.headers).get(b"content-length")
                if length is not None and int(length) > self.max_body:
                    raise _Refused(413, f"a request body is at most {self.max_body} bytes")
            elif isinstance(event, h11.Data):
                body += event.data
                if len(body) > self.max_body:
                    raise _Refused(413, f"a request body is at most {self.max_body} bytes")
            elif isinstance(event, h11.EndOfMessage):
                break
            elif isinstance(event, h11.ConnectionClosed):
                raise ConnectionError("the client closed")
        if head is None:                        # h11 gives the head before the end of a message
            raise ConnectionError("a message without a request head")
        target = head.target.decode("latin-1")
        path, _, query = target.partition("?")
        headers = {name.decode("latin-1").lower(): value.decode("latin-1") for name, value in head.headers}
        return Request(head.method.decode("ascii"), path, urllib.parse.parse_qs(query, keep_blank_values=True),
                       headers, bytes(body), writer.get_extra_info("peername") or ("", 0),
                       writer.get_extra_info("sockname") or ("", 0))

    def _check_host(self, request: Request) -> None:
        if self.allowed_hosts is None:
            return
        given = request.headers.get("host", "")
        if host_of(given) not in self.allowed_hosts:
            log.warning("%s: a request for host %r refused (not a name of this server; by %s)", self.what,
                        given[:80], request.peer_text)
            raise _Refused(421, f"this server does not answer for {given[:80]!r}: use the address it listens "
                                f"on or localhost (web.allowed_hosts)")

    def _refusal(self, status: int, message: str) -> Response:
        body, content_type = self.error_body(status, message)
        return Response(status, body, content_type)

    # -- responses ------------------------------------------------------------------------------
    async def _send(self, writer: asyncio.StreamWriter, data: bytes) -> None:
        if data:
            writer.write(data)
            await asyncio.wait_for(writer.drain(), SEND_TIMEOUT_S)

    async def _respond(self, writer: asyncio.StreamWriter, connection: h11.Connection, response: Response) -> None:
        headers = [("Content-Type", response.content_type), ("Content-Length", str(len(response.body))),
                   ("Connection", "close"), *SECURITY_HEADERS, *response.headers]
        try:
            data = connection.send(h11.Response(status_code=response.status, headers=headers,
                                                reason=h11_reason(response.status).encode("ascii")))
            data += connection.send(h11.Data(data=response.body)) + connection.send(h11.EndOfMessage())
        except h11.LocalProtocolError:          # no request was read (or not as h11 takes it): answer plainly
            await self._raw_refusal(writer, response.status, response.body.decode("utf-8", "replace"),
                                    response.content_type)
            return
        try:
            await self._send(writer, data)
        except (ConnectionError, asyncio.TimeoutError):
            pass

    async def _raw_refusal(self, writer: asyncio.StreamWriter, status: int, message: str,
                           content_type: str | None = None) -> None:
        if content_type is None:
            body, content_type = self.error_body(status, message)
        else:
            body = message.encode("utf-8")
        head = (f"HTTP/1.1 {status} {h11_reason(status)}\r\nContent-Type: {content_type}\r\n"
                f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n")
        try:
            await self._send(writer, head.encode("latin-1") + body)
        except (ConnectionError, asyncio.TimeoutError):
            pass
        finally:
            writer.close()

    async def _stream(self, writer: asyncio.StreamWriter, connection: h11.Connection, place: _Place,
                      stream: EventStream) -> None:
        if self.max_streams and self.streams >= self.max_streams:
            streams = [other for other in self.places.values() if other.state == _Place.STREAM]
            victim = max(streams, key=lambda other: (other.unread_bytes, -other.opened))
            self.counts["closed_for_room"] += 1
            victim.close("closed to make room for a newer page")
        place.state = _Place.STREAM
        place.writer.transport.get_extra_info("socket").setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 65536)
        headers = [("Content-Type", "text/event-stream"), ("Connection", "close"), *SECURITY_HEADERS,
                   *stream.headers]
        await self._send(writer, connection.send(h11.Response(status_code=200, headers=headers, reason=b"OK")))
        async for frame in stream.frames():
            await self._send(writer, connection.send(h11.Data(data=frame)))


def host_of(header: str) -> str:
    """The host a ``Host`` header names, without its port, in lower case (``[::1]:80`` -> ``::1``)."""
    if header.startswith("["):
        return header[1:].partition("]")[0].lower()
    if header.count(":") == 1:
        return header.partition(":")[0].lower()
    return header.lower()                       # no port, or a bare IPv6 address


def h11_reason(status: int) -> str:
    """The reason phrase of an HTTP status."""
    import http

    try:
        return http.HTTPStatus(status).phrase
    except ValueError:
        return "Error"


__all__ = ["HttpServer", "Request", "Response", "EventStream", "HEAD_TIMEOUT_S", "STREAM_STALL_S"]
