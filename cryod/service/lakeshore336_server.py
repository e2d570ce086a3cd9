"""The Lake Shore 336 command set over TCP (``lakeshore336: {address, writable}``), as a 336's Ethernet port.

Off unless the configuration has a ``lakeshore336`` section. A client connects, sends messages
ending in a line feed and reads the replies to its queries, as from a 336's TCP socket (manual
section 6.4.3; the 336 listens on port 7777, the example configuration too). The protocol is
:mod:`cryod.service.lakeshore336`; here are the connection's limits, which keep any client from
changing what it may not or slowing the loop:

* at most :data:`MAX_CLIENTS` connections at once; one more is closed at once (a 336 takes few);
* a message longer than :data:`~cryod.service.lakeshore336.MAX_MESSAGE` characters is dropped
  unread up to its line feed (CME in ``*ESR?``), so a flood without line feeds costs a few
  kilobytes of memory, not more;
* a connection is closed after :data:`IDLE_TIMEOUT_S` without a complete message, and when it does
  not read its replies within :data:`~cryod.service.tcp_service.SEND_TIMEOUT_S`;
* each connection is served at most :data:`MESSAGES_PER_S` messages a second (a faster client is
  read more slowly: TCP holds the rest), so the interface's share of the processor, and of the
  Python interpreter the loop shares, stays bounded whatever the clients send;
* writes go through the loop's commands and their limits, each journaled with the peer, and the
  connection waits for the loop's answer before its next message: a query after ``SETP`` shows
  the new setpoint.
"""

from __future__ import annotations

import asyncio
import time
from typing import Callable

from cryod.service.commands import Command
from cryod.service.lakeshore336 import MAX_MESSAGE, Lakeshore336Session, split_message
from cryod.service.async_clients import loop_answer
from cryod.service.tcp_service import TcpService, send

#: Connections open at once.
MAX_CLIENTS = 16
#: A connection without a complete message for this long is closed, s (a dead client frees its place).
IDLE_TIMEOUT_S = 900.0
#: Messages served per connection and second, at most.
MESSAGES_PER_S = 50
#: How long a write waits for the loop's answer, s.
REPLY_TIMEOUT_S = 5.0


class Lakeshore336Server(TcpService):
    """Serves the 336's command set from its own thread.

    Parameters
    ----------
    address : str
        ``host:port``.
    writable : bool
        Whether SETP, RAMP and RANGE reach the loop.
    status : callable
        The loop's status as a dict, with the thermometers' resistances (``T2_ohm``, ``T5_ohm``).
    submit : callable
        Hands a command to the loop (the daemon's, as for the control socket).
    setup : callable
        The :class:`~cryod.service.lakeshore336.Lakeshore336Setup` of the configuration in force.
    idle_timeout_s : float, optional
        Default :data:`IDLE_TIMEOUT_S`.
    max_clients : int, optional
        Default :data:`MAX_CLIENTS`.
    """

    def __init__(self, address: str, writable: bool, status: Callable[[], dict],
                 submit: Callable[[Command], Command], setup: Callable, idle_timeout_s: float | None = None,
                 max_clients: int | None = None):
        super().__init__("Lake Shore 336 command set" + (" (writable)" if writable else " (read-only)"), address,
                         MAX_CLIENTS if max_clients is None else max_clients)
        self.writable = writable
        self.status = status
        self.submit = submit
        self.setup = setup
        self.idle_timeout_s = IDLE_TIMEOUT_S if idle_timeout_s is None else idle_timeout_s
        #: Messages answered since the start (all clients).
        self.messages = 0

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, peer: str) -> None:
        session = Lakeshore336Session(self.setup, self.writable, peer)
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
                reply = await self._answer(session, raw)
                if reply is not None:
                    await send(writer, reply.encode("ascii") + b"\r\n")

    async def _answer(self, session: Lakeshore336Session, raw: bytes) -> str | None:
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
            status = self.status() if status is None else status
            outcome = session.respond(part, status)
            if isinstance(outcome, Command):
                session.answered(await loop_answer(outcome, self.submit, REPLY_TIMEOUT_S))
                status = None               # what follows sees the command's effect
            elif outcome is not None:
                replies.append(outcome)
        return ";".join(replies) if replies else None
