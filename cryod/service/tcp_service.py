"""A TCP interface of the daemon served from a thread of its own: the web page, the Lake Shore 336 commands.

One thread runs an asyncio event loop that serves every client of the interface, so however many
connect, the interface competes with the control loop's thread as one thread. What each interface
shares lives here:

* the address: ``host:port`` from its configuration section, loopback unless the address says
  otherwise; the journal says at start where it listens, with a warning when that is not loopback
  (:mod:`cryod.listen_address`);
* a limit on connections open at once (one more is told it is busy and closed);
* TCP keepalive, so a client that vanished without closing frees its place;
* a client's trouble (an exception in its handler) ends that client only;
* commands go to the loop like every other path's, and the interface waits for the loop's answer
  without blocking its thread (:func:`cryod.service.async_clients.loop_answer`).

A subclass gives :meth:`TcpService.serve` (one client) and may give :meth:`TcpService.busy`
(the reply to a client over the limit) and :meth:`TcpService.background` (a task that runs while
the interface does, e.g. the web page's history).
"""

from __future__ import annotations

import asyncio
import logging
import socket

from cryod.service.async_clients import ClientsThread
from cryod.listen_address import describe, is_loopback, parse_address

log = logging.getLogger("cryod.network")

#: Connections the kernel holds until the interface takes them.
BACKLOG = 64
#: How long a reply may wait for a client that does not read it, s.
SEND_TIMEOUT_S = 5.0


class TcpService:
    """One TCP interface: listens, serves each client with :meth:`serve`, stops.

    Parameters
    ----------
    what : str
        The interface's name in the journal (``"web page"``).
    address : str
        ``host:port`` (port 0: any free port, see :attr:`port`).
    max_clients : int
        Connections open at once; one more gets :meth:`busy` and is closed.
    stream_limit : int
        Longest line ``reader.readuntil`` takes, bytes (longer: ``asyncio.LimitOverrunError``).
    """

    def __init__(self, what: str, address: str, max_clients: int, stream_limit: int = 2 ** 16):
        self.what = what
        self.host, self.port = parse_address(address, allow_any_port=True)
        self.max_clients = max_clients
        self.stream_limit = stream_limit
        #: Connections open now, the most at once since the start, and those refused as busy.
        self.clients = 0
        self.most_clients = 0
        self.busy_refusals = 0
        self._thread: ClientsThread | None = None

    # -- what a subclass gives -------------------------------------------------------
    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, peer: str) -> None:
        """Serve one client until it is done (the connection is closed after)."""
        raise NotImplementedError

    async def busy(self, writer: asyncio.StreamWriter) -> None:
        """Tell a client over :attr:`max_clients` that the interface is busy (default: nothing)."""

    async def background(self) -> None:
        """Runs beside the clients while the interface serves (default: nothing)."""

    # -- clients ----------------------------------------------------------------------
    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.clients >= self.max_clients:
            self.busy_refusals += 1
            try:
                await self.busy(writer)
            finally:
                await close(writer)
            return
        self.clients += 1
        self.most_clients = max(self.most_clients, self.clients)
        connection = writer.get_extra_info("socket")
        if connection is not None:
            try:
                connection.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
            except OSError:
                pass
        address = writer.get_extra_info("peername")
        peer = f"{address[0]}:{address[1]}" if isinstance(address, tuple) else "an unknown peer"
        try:
            await self.serve(reader, writer, peer)
        except asyncio.CancelledError:
            pass                                # the daemon is stopping
        except (ConnectionError, asyncio.IncompleteReadError, asyncio.TimeoutError):
            pass                                # the client went away or stopped reading
        except Exception as error:              # one client's trouble never ends the interface
            log.warning("%s: a client's request failed (%s): %s: %s", self.what, peer, type(error).__name__, error)
        finally:
            self.clients -= 1
            await close(writer)

    # -- running ------------------------------------------------------------------------
    def start(self) -> None:
        """Listen and serve from a thread; an address in use or not on this host raises OSError naming it."""
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        listener = socket.socket(family, socket.SOCK_STREAM)
        try:
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind(("127.0.0.1" if self.host == "localhost" else self.host, self.port))
            listener.listen(BACKLOG)
        except OSError as error:
            listener.close()
            raise OSError(f"{self.what} on {self.host}:{self.port}: {error.strerror or error}") from error
        listener.setblocking(False)
        self.port = listener.getsockname()[1]
        self._thread = ClientsThread(self.what, self._open_server)
        self._thread.start(listener)
        log.log(logging.INFO if is_loopback(self.host) else logging.WARNING, "%s",
                describe(self.what, self.host, self.port))

    async def _open_server(self, listener: socket.socket) -> asyncio.AbstractServer:
        server = await asyncio.start_server(self._client, sock=listener, backlog=BACKLOG, limit=self.stream_limit)
        asyncio.ensure_future(self.background())        # cancelled with the clients at the stop
        return server

    def stop(self) -> None:
        """Stop serving and close the port (open connections are closed)."""
        if self._thread is not None:
            self._thread.stop()
            self._thread = None


async def send(writer: asyncio.StreamWriter, data: bytes) -> None:
    """Write ``data`` and wait until the client took it (:data:`SEND_TIMEOUT_S`, else TimeoutError)."""
    writer.write(data)
    await asyncio.wait_for(writer.drain(), SEND_TIMEOUT_S)


async def close(writer: asyncio.StreamWriter) -> None:
    """Close a connection, whatever state the client left it in."""
    try:
        writer.close()
        await asyncio.wait_for(writer.wait_closed(), 1.0)
    except (OSError, asyncio.TimeoutError, asyncio.CancelledError):
        pass
