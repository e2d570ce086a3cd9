"""Serve simulated instruments on 127.0.0.1 so the real drivers reach them through pyvisa-py.

:class:`ScpiServer` puts one simulated instrument on a TCP port, as a
LAN-to-GPIB gateway or an instrument's own raw-socket port would: one
program message per line (LF, CR ignored), one reply line per query. The
drivers open it as ``TCPIP0::127.0.0.1::<port>::SOCKET``; port 0 asks the
operating system for a free port, reported by :attr:`ScpiServer.port`.

A dropped connection (the device's ``drop_connections()`` fault) closes the
sockets of every connection open at that moment; new connections are
accepted again, so a transport's ``reopen()`` recovers.

Examples
--------
>>> from drivers.clock import VirtualClock
>>> from simulated_hw.instrument import EmulatedInstrument
>>> device = EmulatedInstrument(VirtualClock(), "ACME,MODEL 1,0,0")
>>> with ScpiServer(device) as server:
...     server.resource_name.startswith("TCPIP0::127.0.0.1::")
True
"""

from __future__ import annotations

import select
import socket
import threading
from typing import Generic, Protocol, Self, TypeVar

#: How often a connection thread looks at the stop flag and the device's session (s).
POLL_INTERVAL_S = 0.01

#: What a subclass keeps for each connection (what its new_connection gives).
StateT = TypeVar("StateT")


class ThreadedTcpServer(Generic[StateT]):
    """A TCP listener on 127.0.0.1 with one thread per connection; subclasses handle the bytes, each connection
    with the state their :meth:`new_connection` gives it."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        self.host = host
        self._requested_port = port
        self._listener: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._connections: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._stopping = threading.Event()

    @property
    def port(self) -> int:
        if self._listener is None:
            raise RuntimeError("server is not started")
        return self._listener.getsockname()[1]

    def start(self) -> Self:
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind((self.host, self._requested_port))
        listener.listen(8)
        self._listener = listener
        self._spawn(self._accept_loop, listener)
        return self

    def stop(self) -> None:
        self._stopping.set()
        if self._listener is not None:
            self._listener.close()
        with self._lock:
            for connection in list(self._connections):
                self._shut(connection)
        for thread in self._threads:
            thread.join(timeout=2.0)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()

    def drop_connections(self) -> None:
        """Fault: close every connection open now (new ones are accepted)."""
        with self._lock:
            for connection in list(self._connections):
                self._shut(connection)

    def _shut(self, connection: socket.socket) -> None:
        self._connections.discard(connection)
        try:
            connection.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        connection.close()

    def _spawn(self, target, *arguments) -> None:
        thread = threading.Thread(target=target, args=arguments, daemon=True)
        self._threads.append(thread)
        thread.start()

    def _accept_loop(self, listener: socket.socket) -> None:
        while not self._stopping.is_set():
            try:
                ready, _, _ = select.select([listener], [], [], POLL_INTERVAL_S * 10)
                if not ready:
                    continue
                connection, _ = listener.accept()
            except (OSError, ValueError):
                return
            connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._connections.add(connection)
            self._spawn(self._serve, connection)

    def _serve(self, connection: socket.socket) -> None:
        state = self.new_connection()
        buffer = b""
        try:
            while not self._stopping.is_set() and connection in self._connections:
                if not self.connection_alive(state):
                    break
                ready, _, _ = select.select([connection], [], [], POLL_INTERVAL_S)
                if not ready:
                    continue
                data = connection.recv(4096)
                if not data:
                    break
                buffer = self.received(state, buffer + data, connection)
        except OSError:
            pass
        finally:
            with self._lock:
                if connection in self._connections:
                    self._shut(connection)

    # -- for subclasses -------------------------------------------------------------
    def new_connection(self) -> StateT:
        """Per-connection state."""
        raise NotImplementedError

    def connection_alive(self, state: StateT) -> bool:
        return True

    def received(self, state: StateT, buffer: bytes, connection: socket.socket) -> bytes:
        """Handle what has arrived; return what is left over (an incomplete line)."""
        raise NotImplementedError


class ServedDevice(Protocol):
    def open_session(self) -> int: ...

    def session_alive(self, session: int) -> bool: ...

    def handle(self, message: str) -> str | None: ...


class ScpiServer(ThreadedTcpServer[int]):
    """One simulated instrument on a raw TCP socket (``TCPIP0::127.0.0.1::<port>::SOCKET``).

    Parameters
    ----------
    device : ServedDevice
        The simulated instrument.
    host, port : str, int
        Where to listen; port 0 picks a free one.
    """

    def __init__(self, device: ServedDevice, host: str = "127.0.0.1", port: int = 0):
        super().__init__(host, port)
        self.device = device

    @property
    def resource_name(self) -> str:
        """The VISA resource name of this server."""
        return f"TCPIP0::{self.host}::{self.port}::SOCKET"

    def new_connection(self) -> int:
        return self.device.open_session()

    def connection_alive(self, state: int) -> bool:
        return self.device.session_alive(state)

    def received(self, state: int, buffer: bytes, connection: socket.socket) -> bytes:
        while b"\n" in buffer:
            line, buffer = buffer.split(b"\n", 1)
            if not self.device.session_alive(state):
                raise OSError("connection dropped")
            reply = self.device.handle(line.decode("ascii", "replace").rstrip("\r"))
            if reply is not None:
                connection.sendall(reply.encode("ascii", "replace") + b"\n")
        return buffer
