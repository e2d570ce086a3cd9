"""The control socket's server for many clients: one thread, and a bound on the connections open at once.

The control socket serves every client (and the live stream's subscribers) from one thread with
an asyncio event loop (:class:`ClientsThread`), so many clients cost the loop what one thread
costs, not one thread each. What bounds them is the number of connections (file descriptors,
memory): :class:`ConnectionBook` allows ``most_open`` at once. A client that connects and says
nothing holds one until its request's timeout; many such clients (a stuck script, a scanner, a
flood) would hold them all, and a client with something to say (``cryod ctl heater-off``) would
find no room. So a new connection beyond ``most_open`` is not turned away: the connection that
has waited longest without sending its request is closed to make room for it (it has had its
chance; a client sends its request as it connects). Connections whose request is being answered
are never closed for room; when all of them are, a new connection may take one of ``reserved``
more places (the control socket serves only ``heater-off`` on those), and beyond those it is
refused at once.

Examples
--------
>>> book = ConnectionBook(most_open=2)
>>> book.most_open, book.open
(2, 0)
"""

from __future__ import annotations

import asyncio
import collections
import logging
import socket
import threading
from typing import Awaitable, Callable

from cryod.service.commands import TAKEN_ANSWER_WAIT_S, Command, no_answer

log = logging.getLogger("cryod.clients")


def _connection_task() -> asyncio.Task:
    """The running task: a connection's (the book is kept from its clients' tasks)."""
    task = asyncio.current_task()
    if task is None:
        raise RuntimeError("the connection book is kept from a client's task")
    return task


class ConnectionBook:
    """Which connections (their asyncio tasks) are open, and which of them still wait for their request.

    Parameters
    ----------
    most_open : int
        Connections open at once for any request; one more closes the one that has waited longest for
        its request.
    reserved : int
        Places beyond ``most_open`` for when every connection open is being answered.
    """

    #: What :meth:`arrived` says of a new connection: a place like any other, one of the reserved places
    #: (when all others are being answered), or none (refuse it at once).
    TAKEN, RESERVED, FULL = "taken", "reserved", "full"

    def __init__(self, most_open: int, reserved: int = 0):
        self.most_open = int(most_open)
        self.reserved = int(reserved)
        #: Connections open now, the most at once since the start, and those closed to make room.
        self.open = 0
        self.most_seen = 0
        self.closed_for_room = 0
        self._waiting: collections.OrderedDict[asyncio.Task, None] = collections.OrderedDict()
        self._evicted: set[asyncio.Task] = set()

    def arrived(self) -> str:
        """The running task's connection is open and waits for its request; makes room if needed.

        Returns
        -------
        str
            :attr:`TAKEN`, :attr:`RESERVED` or :attr:`FULL` (the caller refuses it at once).
        """
        task = _connection_task()
        self.open += 1
        self.most_seen = max(self.most_seen, self.open)
        live = self.open - len(self._evicted)
        while live > self.most_open and self._waiting:
            oldest, _ = self._waiting.popitem(last=False)
            self._evicted.add(oldest)
            self.closed_for_room += 1
            oldest.cancel()
            live -= 1
        self._waiting[task] = None
        if live <= self.most_open:
            return self.TAKEN
        return self.RESERVED if live <= self.most_open + self.reserved else self.FULL

    def request_received(self) -> None:
        """The running task's connection has sent its request: it is no longer closed for room."""
        self._waiting.pop(_connection_task(), None)

    def closed_for_room_now(self) -> bool:
        """Whether the running task was cancelled to make room (rather than because the server stops)."""
        return asyncio.current_task() in self._evicted

    def left(self) -> None:
        """The running task's connection is closed."""
        task = _connection_task()
        self._waiting.pop(task, None)
        self._evicted.discard(task)
        self.open -= 1


class ClientsThread:
    """A listening socket's clients, served from one thread with an asyncio event loop.

    Parameters
    ----------
    what : str
        What serves, for the thread's name and the journal (``control socket``).
    open_server : callable
        ``await open_server(listener)``: the asyncio server on the listening socket, handling each client
        (``asyncio.start_unix_server(handle, sock=listener, ...)``).
    """

    def __init__(self, what: str, open_server: Callable[[socket.socket], Awaitable[asyncio.AbstractServer]]):
        self.what = what
        self.open_server = open_server
        #: Why serving failed (None while it runs or after a stop).
        self.failure: str | None = None
        self._event_loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Future | None = None
        self._thread: threading.Thread | None = None

    def start(self, listener: socket.socket) -> None:
        """Serve from a thread of its own; OSError when serving could not start."""
        event_loop = self._event_loop = asyncio.new_event_loop()
        ready = threading.Event()
        self.failure = None
        self._thread = threading.Thread(target=self._run, args=(event_loop, listener, ready),
                                        name=f"cryod-{self.what.split()[0]}", daemon=True)
        self._thread.start()
        ready.wait(10.0)
        if self.failure is not None:
            self.stop()
            raise OSError(f"{self.what} could not be served: {self.failure}")

    def _run(self, event_loop: asyncio.AbstractEventLoop, listener: socket.socket, ready: threading.Event) -> None:
        asyncio.set_event_loop(event_loop)
        try:
            event_loop.run_until_complete(self._serve(listener, ready))
        except Exception as error:              # said by start(), or in the journal once serving
            self.failure = f"{type(error).__name__}: {error}"
            log.error("%s stopped: %s", self.what, self.failure)
        finally:
            ready.set()
            event_loop.close()

    async def _serve(self, listener: socket.socket, ready: threading.Event) -> None:
        self._stopping = asyncio.get_running_loop().create_future()
        server = await self.open_server(listener)
        ready.set()
        try:
            await self._stopping
        finally:
            server.close()
            clients = [task for task in asyncio.all_tasks() if task is not asyncio.current_task()]
            for task in clients:
                task.cancel()
            await asyncio.gather(*clients, return_exceptions=True)

    def stop(self) -> None:
        """Stop serving: each client's task is cancelled (it tells its client) and the listener closed."""
        event_loop = self._event_loop
        if self._thread is None or event_loop is None:
            return
        try:
            event_loop.call_soon_threadsafe(resolve, self._stopping)
        except RuntimeError:                    # the event loop has already ended
            pass
        self._thread.join(5.0)
        self._thread = None


def resolve(future: asyncio.Future | None) -> None:
    """Complete ``future`` (someone's waiter), unless it is done already (on the event loop's thread)."""
    if future is not None and not future.done():
        future.set_result(None)


__all__ = ["ClientsThread", "ConnectionBook", "resolve"]


async def loop_answer(command: Command, submit, timeout_s: float) -> Command:
    """Hand ``command`` to the loop with ``submit`` and wait for its answer without blocking the event loop.

    After ``timeout_s`` without an answer the command is withdrawn, so that the loop never carries it out
    later (:func:`cryod.service.commands.no_answer`); when the loop had taken it already, its answer is
    waited for :data:`~cryod.service.commands.TAKEN_ANSWER_WAIT_S` more.

    Returns
    -------
    Command
        Answered, or marked refused with the reason.
    """
    event_loop = asyncio.get_running_loop()
    answered = event_loop.create_future()

    def wake() -> None:                     # on the loop's thread: hand over, never raise
        try:
            event_loop.call_soon_threadsafe(resolve, answered)
        except RuntimeError:                # the interface has stopped meanwhile
            pass

    command.on_answer = wake
    submit(command)
    for wait_s in (timeout_s, TAKEN_ANSWER_WAIT_S):
        if command.done.is_set():
            return command
        try:
            await asyncio.wait_for(asyncio.shield(answered), wait_s)
        except asyncio.TimeoutError:
            if command.withdraw():
                break
    if command.done.is_set():
        return command
    return no_answer(command, timeout_s)
