"""Replay of exact SCPI exchanges: a transport that expects given (command, reply) pairs.

In the spirit of PyMeasure's ``expected_protocol``: a driver method is run
against a list of ``(command, reply)`` pairs, ``reply`` None for a write.
Any other command, or one too many, fails the test at once, naming what was
expected; a pair left over fails it at the end. A changed command string
therefore breaks a test. A reply that is an exception is raised instead (a
link that drops, an instrument that does not answer), and ``("<REOPEN>", None)``
expects the connection to be opened again.
"""

from __future__ import annotations

import contextlib

from drivers.errors import InstrumentTimeout


class ProtocolMismatch(AssertionError):
    pass


class ReplayTransport:
    """A :class:`drivers.transports.base.Transport` that replays a fixed exchange."""

    def __init__(self, exchange, name: str = "replay"):
        self.exchange = list(exchange)
        self.position = 0
        self.name = name
        self.timeout_s = 1.0
        self.triggers = 0
        self.closed = False
        self._reply: str | None = None

    def _next(self, command: str):
        if self.position >= len(self.exchange):
            raise ProtocolMismatch(f"unexpected command {command!r} after the last expected one")
        expected_command, reply = self.exchange[self.position]
        if command != expected_command:
            raise ProtocolMismatch(f"exchange {self.position}: sent {command!r}, expected {expected_command!r}")
        self.position += 1
        if isinstance(reply, BaseException):
            raise reply
        return reply

    def write(self, command: str) -> None:
        reply = self._next(command)
        if reply is not None:
            self._reply = reply

    def read(self) -> str:
        if self._reply is None:
            raise InstrumentTimeout(self.name, "nothing to read in the replayed exchange")
        reply, self._reply = self._reply, None
        return reply

    def query(self, command: str) -> str:
        reply = self._next(command)
        if reply is None:
            raise ProtocolMismatch(f"exchange {self.position - 1}: {command!r} is a query but no reply is given")
        return reply

    def trigger(self) -> None:
        self._next("<GET>")
        self.triggers += 1

    def close(self) -> None:
        self.closed = True

    def reopen(self) -> None:
        self._next("<REOPEN>")
        self.closed = False

    def assert_done(self) -> None:
        if self.position != len(self.exchange):
            left = self.exchange[self.position:]
            raise ProtocolMismatch(f"{len(left)} expected exchange(s) never happened, first {left[0]!r}")


@contextlib.contextmanager
def expected_protocol(exchange):
    """``with expected_protocol([...]) as transport:`` build and exercise a driver on ``transport``."""
    transport = ReplayTransport(exchange)
    yield transport
    transport.assert_done()
