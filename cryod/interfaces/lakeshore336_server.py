"""The Lake Shore 336 command set over TCP (``lakeshore336: {address, writable, write_from}``), as a 336's port.

Off unless the configuration has a ``lakeshore336`` section; served by the interfaces process. A
client connects, sends messages ending in a line feed and reads the replies to its queries, as from
a 336's TCP socket (manual section 6.4.3; the 336 listens on port 7777, the example configuration
too). The protocol is :mod:`cryod.service.lakeshore336`; here are the connection's limits, which keep
any client from changing what it may not or keeping others out:

* at most :data:`MAX_CLIENTS` connections at once; one more takes the place of the connection that
  has been idle longest (a 336 client sends its message as it connects), so idle connections,
  however many, never keep a real client out;
* a message longer than :data:`~cryod.service.lakeshore336.MAX_MESSAGE` characters is dropped
  unread up to its line feed (CME in ``*ESR?``), so a flood without line feeds costs a few
  kilobytes of memory, not more;
* a connection is closed after :data:`IDLE_TIMEOUT_S` without a complete message, and when it does
  not read its replies within :data:`SEND_TIMEOUT_S`;
* each connection is served at most :data:`MESSAGES_PER_S` messages a second (a faster client is
  read more slowly: TCP holds the rest);
* writes (``SETP``, ``RAMP``, ``RANGE``) with ``lakeshore336.writable: true`` are taken from a client on
  this computer only when its user may use the control socket (the kernel's socket table names the
  user, :mod:`cryod.interfaces.peers`), and from another computer only when its address is in
  ``lakeshore336.write_from``; each goes to the daemon through the control socket, its limits and its
  journal with the client's address and user, and the connection waits for the daemon's answer before
  its next message: a query after ``SETP`` shows the new setpoint.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import socket
import time
from pathlib import Path
from typing import Callable

from cryod.config import Lakeshore336Config
from cryod.interfaces.daemon_link import DaemonLink
from cryod.interfaces.mirror import DaemonMirror
from cryod.interfaces.peers import is_loopback, loopback_peer, may_use_socket, user_name
from cryod.listen_address import describe, parse_address
from cryod.listen_address import is_loopback as listens_on_loopback
from cryod.service.commands import Command
from cryod.service.daemon_status import DaemonStatus, status_from_json
from cryod.service.lakeshore336 import MAX_MESSAGE, Lakeshore336Session, split_message

log = logging.getLogger("cryod.lakeshore336")

#: Connections open at once; one more takes the place of the idlest.
MAX_CLIENTS = 16
#: A connection without a complete message for this long is closed, s (a dead client frees its place).
IDLE_TIMEOUT_S = 900.0
#: Messages served per connection and second, at most.
MESSAGES_PER_S = 50
#: How long a reply may wait for a client that does not read it, s.
SEND_TIMEOUT_S = 5.0


class _Connection:
    def __init__(self, task: asyncio.Task, writer: asyncio.StreamWriter):
        self.task = task
        self.writer = writer
        self.last_message = time.monotonic()
        self.answering = False
        #: The daemon's status in its answer to this connection's last command: newer than the stream's until
        #: the stream catches up (a query after SETP shows the new setpoint).
        self.after_command: DaemonStatus | None = None


class Lakeshore336Server:
    """Serves the 336's command set on the interfaces process's event loop.

    Parameters
    ----------
    config : Lakeshore336Config
    setup : callable
        The :class:`~cryod.service.lakeshore336.Lakeshore336Setup` of the configuration in force.
    mirror : DaemonMirror
        The daemon's status and its latest row (the thermometers' resistances).
    link : DaemonLink
        Writes go through it.
    socket_path : pathlib.Path
        The daemon's control socket, whose permissions say which users on this computer may write.
    idle_timeout_s : float, optional
        Default :data:`IDLE_TIMEOUT_S`.
    """

    def __init__(self, config: Lakeshore336Config, setup: Callable, mirror: DaemonMirror, link: DaemonLink,
                 socket_path: Path, idle_timeout_s: float | None = None, max_clients: int | None = None):
        self.config = config
        self.what = "Lake Shore 336 command set" + (" (writable)" if config.writable else " (read-only)")
        self.host, self.port = parse_address(config.address, allow_any_port=True)
        self.setup = setup
        self.mirror = mirror
        self.link = link
        self.socket_path = Path(socket_path)
        self.idle_timeout_s = IDLE_TIMEOUT_S if idle_timeout_s is None else idle_timeout_s
        self.max_clients = MAX_CLIENTS if max_clients is None else max_clients
        self.connections: dict[asyncio.Task, _Connection] = {}
        #: Messages answered since the start, connections closed to make room.
        self.messages = 0
        self.closed_for_room = 0
        self._server: asyncio.AbstractServer | None = None

    async def start(self) -> None:
        """Listen; an address in use or not on this host raises OSError naming it."""
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        listener = socket.socket(family, socket.SOCK_STREAM)
        try:
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind(("127.0.0.1" if self.host == "localhost" else self.host, self.port))
            listener.listen(64)
        except OSError as error:
            listener.close()
            raise OSError(f"{self.what} on {self.host}:{self.port}: {error.strerror or error}") from error
        listener.setblocking(False)
        self.port = listener.getsockname()[1]
        self._server = await asyncio.start_server(self._client, sock=listener)
        log.log(logging.INFO if listens_on_loopback(self.host) else logging.WARNING, "%s",
                describe(self.what, self.host, self.port))

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
        for connection in list(self.connections.values()):
            connection.task.cancel()

    # -- who may write ---------------------------------------------------------------------------
    def client(self, writer: asyncio.StreamWriter) -> tuple[str, str | None]:
        """The client in words (address, and user on this computer) and why it may not write (None: it may)."""
        peer = writer.get_extra_info("peername") or ("", 0)
        here = writer.get_extra_info("sockname") or ("", 0)
        address = f"[{peer[0]}]:{peer[1]}" if ":" in peer[0] else f"{peer[0]}:{peer[1]}"
        if is_loopback(peer[0]):
            found = loopback_peer(peer[:2], here[:2])
            if found is None:
                return address, "its user could not be found in the kernel's socket table"
            words = f"{address}, uid {found.uid} ({user_name(found.uid)})"
            if not may_use_socket(found.uid, self.socket_path):
                return words, (f"uid {found.uid} ({user_name(found.uid)}) may not use the control socket "
                               f"{self.socket_path} (control_socket.mode/group)")
            return words, None
        if peer[0] in self.config.write_from:
            return address, None
        return address, f"{peer[0]} is not in lakeshore336.write_from"

    # -- clients ----------------------------------------------------------------------------------
    def _make_room(self) -> None:
        if len(self.connections) < self.max_clients:
            return
        idle = [connection for connection in self.connections.values() if not connection.answering]
        victim = min(idle or self.connections.values(), key=lambda connection: connection.last_message)
        self.closed_for_room += 1
        victim.writer.transport.abort()
        victim.task.cancel()
        self.connections.pop(victim.task, None)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None                 # a client is served in a task of its own
        self._make_room()
        connection = self.connections[task] = _Connection(task, writer)
        sock = writer.get_extra_info("socket")
        if sock is not None:
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
            except OSError:
                pass
        words, refusal = self.client(writer)
        session = Lakeshore336Session(self.setup, self.config.writable, words, refusal)
        try:
            await self._serve(reader, writer, session, connection)
        except (asyncio.CancelledError, ConnectionError, asyncio.IncompleteReadError, asyncio.TimeoutError):
            pass                                # closed for room, stopping, a client gone or not reading
        except Exception as error:              # one client's trouble never ends the interface
            log.warning("%s: a client's request failed (%s): %s: %s", self.what, words, type(error).__name__, error)
        finally:
            self.connections.pop(task, None)
            writer.transport.abort()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, session: Lakeshore336Session,
                     connection: _Connection) -> None:
        pending = bytearray()
        dropping = False                    # inside a message too long to take, until its line feed
        second, served = 0.0, 0
        while True:
            chunk = await asyncio.wait_for(reader.read(4096), self.idle_timeout_s)
            if not chunk:
                return                      # the client closed (mid-message: that message is dropped)
            pending += chunk
            while True:
                end = pending.find(b"\n")
                if end < 0:
                    if len(pending) > MAX_MESSAGE + 1:          # (a carriage return may follow)
                        del pending[:]
                        if not dropping:
                            session.malformed()
                        dropping = True
                    break
                raw = bytes(pending[:end]).rstrip(b"\r")
                del pending[:end + 1]
                connection.last_message = time.monotonic()
                if dropping:
                    dropping = False
                    continue
                now = time.monotonic()
                if now - second >= 1.0:
                    second, served = now, 0
                served += 1
                if served > MESSAGES_PER_S:
                    await asyncio.sleep(1.0 - (now - second))
                    second, served = time.monotonic(), 1
                connection.answering = True
                try:
                    reply = await self._answer(session, raw, connection)
                finally:
                    connection.answering = False
                    connection.last_message = time.monotonic()
                if reply is not None:
                    writer.write(reply.encode("ascii") + b"\r\n")
                    await asyncio.wait_for(writer.drain(), SEND_TIMEOUT_S)

    def _status(self, connection: _Connection) -> DaemonStatus:
        """The daemon's status with the thermometers' resistances of its latest row (``SRDG?``): the stream's, or
        the one the daemon answered this connection's last command with while the stream has not reached it."""
        status = self.mirror.status()
        newer = connection.after_command
        if newer is not None and not status.loop.time_s >= newer.loop.time_s:
            return dataclasses.replace(newer, flange_ohm=status.flange_ohm, ptc_stage_ohm=status.ptc_stage_ohm)
        connection.after_command = None
        return status

    async def _answer(self, session: Lakeshore336Session, raw: bytes, connection: _Connection) -> str | None:
        """The reply line to one message (None when it holds no query that is answered)."""
        self.messages += 1
        if len(raw) > MAX_MESSAGE:
            session.malformed()
            return None
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            session.malformed()              # not the 336's character set: a malformed message (CME)
            return None
        replies = []
        status = None
        for part in split_message(text):
            status = self._status(connection) if status is None else status
            outcome = session.respond(part, status)
            if isinstance(outcome, Command):
                reply = await self.link.command(outcome.line, outcome.sender)
                outcome.ok, outcome.message = bool(reply.get("ok")), str(reply.get("message", ""))
                session.answered(outcome)
                if isinstance(reply.get("status"), dict):       # what follows sees the command's effect
                    connection.after_command = status_from_json(reply["status"])
                status = None
            elif outcome is not None:
                replies.append(outcome)
        return ";".join(replies) if replies else None


__all__ = ["Lakeshore336Server", "MAX_CLIENTS", "IDLE_TIMEOUT_S"]
