"""The interfaces process's lines to the daemon: its stream in, its clients' commands out.

Both go through the daemon's control socket. The stream is one connection that sends
``subscribe`` (``subscribe SEQ`` after a lost connection, for the events it missed) and then
reads its lines (one per row of the loop, and one every 100 ms at least) into the :class:`~cryod.interfaces.mirror.DaemonMirror`; the process's
report goes up the same connection. A command is a connection of its own that sends
``relay {"sender": ..., "command": ...}``: the daemon journals it with the client the web page or
the 336 saw (its address, and for a client on this computer its user) and this process's user,
and answers it as it answers ``cryod ctl``.
"""

from __future__ import annotations

import asyncio
import json
import logging
from pathlib import Path
from typing import Callable

from cryod.interfaces.mirror import DaemonMirror

log = logging.getLogger("cryod.interfaces")

#: The longest line of the stream taken (the first one holds 20 s of rows and the recent events), bytes.
MAX_STREAM_LINE = 16 * 1024 * 1024
#: Pauses before connecting again after the stream was lost: the first and the longest (s).
RECONNECT_FIRST_S, RECONNECT_LONGEST_S = 0.1, 2.0
#: How long a command waits for the daemon's reply (its loop's own wait is 5 s, the rest is its tick), s.
COMMAND_TIMEOUT_S = 8.0
#: How often the process's report goes up (s).
REPORT_S = 1.0


class DaemonLink:
    """Subscribes to the daemon's stream and relays commands to it.

    Parameters
    ----------
    socket_path : pathlib.Path
        The daemon's control socket.
    mirror : DaemonMirror
        Fed the stream.
    report : callable
        What this process says of itself (a dict), sent up every :data:`REPORT_S`.
    after : int, optional
        The last event a process before this one took (the first subscription asks for what followed).
    """

    def __init__(self, socket_path: Path, mirror: DaemonMirror, report: Callable[[], dict],
                 after: int | None = None):
        self.socket_path = Path(socket_path)
        self.mirror = mirror
        self.report = report
        self.after = after
        #: Lines of the stream taken, and how many times it was lost.
        self.lines = 0
        self.losses = 0

    async def run(self) -> None:
        """Keep the stream (connecting again when it is lost) until cancelled."""
        pause_s = RECONNECT_FIRST_S
        said = False
        while True:
            try:
                await self._subscribed()
                pause_s = RECONNECT_FIRST_S
                said = False
            except (OSError, ConnectionError, ValueError, asyncio.IncompleteReadError,
                    asyncio.LimitOverrunError) as error:
                if not said:
                    log.warning("the daemon's stream at %s: %s; connecting again", self.socket_path, error)
                    said = True
            if self.mirror.connected:
                self.losses += 1
            self.mirror.lost()
            await asyncio.sleep(pause_s)
            pause_s = min(2.0 * pause_s, RECONNECT_LONGEST_S)

    async def _subscribed(self) -> None:
        reader, writer = await asyncio.open_unix_connection(str(self.socket_path), limit=MAX_STREAM_LINE)
        try:
            after = self.mirror.last_seq if self.mirror.last_seq else self.after
            writer.write(f"subscribe{'' if after is None else f' {after}'}\n".encode("ascii"))
            await writer.drain()
            first = json.loads(await reader.readline() or b"null")
            if not isinstance(first, dict) or not first.get("ok"):
                raise ConnectionError(f"the daemon refused the stream: "
                                      f"{first.get('message') if isinstance(first, dict) else 'no answer'}")
            self.mirror.first(first)
            log.info("connected to the daemon's stream (pid %s)", first.get("hello", {}).get("pid"))
            reporter = asyncio.ensure_future(self._report(writer))
            try:
                while True:
                    line = await reader.readline()
                    if not line:
                        raise ConnectionError("the daemon closed its stream")
                    self.mirror.frame(json.loads(line))
                    self.lines += 1
            finally:
                reporter.cancel()
        finally:
            writer.close()

    async def _report(self, writer: asyncio.StreamWriter) -> None:
        while True:
            report = dict(self.report(), last_seq=self.mirror.last_seq)
            writer.write((json.dumps({"report": report}, default=str) + "\n").encode("utf-8"))
            await writer.drain()
            await asyncio.sleep(REPORT_S)

    async def command(self, line: str, sender: str) -> dict:
        """Send ``line`` as ``sender``'s command; the daemon's reply (``ok``, ``message``, ``status``), or a refusal
        that says why there is none."""
        try:
            reader, writer = await asyncio.wait_for(asyncio.open_unix_connection(str(self.socket_path),
                                                                                 limit=MAX_STREAM_LINE), 2.0)
        except (OSError, asyncio.TimeoutError) as error:
            return {"ok": False, "message": f"the daemon cannot be reached ({error}); nothing was done"}
        try:
            writer.write(("relay " + json.dumps({"sender": sender, "command": line}) + "\n").encode("utf-8"))
            await writer.drain()
            raw = await asyncio.wait_for(reader.readline(), COMMAND_TIMEOUT_S)
        except asyncio.TimeoutError:
            return {"ok": False, "message": f"no reply from the daemon within {COMMAND_TIMEOUT_S:g} s"}
        except OSError as error:
            return {"ok": False, "message": f"the daemon's connection failed ({error})"}
        finally:
            writer.close()
        try:
            reply = json.loads(raw)
        except ValueError:
            return {"ok": False, "message": "the daemon's reply could not be read"}
        return reply if isinstance(reply, dict) else {"ok": False, "message": "the daemon's reply could not be read"}


__all__ = ["DaemonLink", "COMMAND_TIMEOUT_S"]
