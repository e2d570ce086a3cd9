"""The daemon's live stream: its rows, events and status, for processes that show them elsewhere.

Everything the lab watches the daemon through, other than ``cryod ctl`` (the web page, the Lake
Shore 336 command set, the metrics, the alarm hooks, an EPICS IOC), runs in a process of its own
and reads the daemon through this stream: a connection to the control socket that sends
``subscribe`` (or ``subscribe SEQ``) gets one JSON line back, then a line as soon as the loop has handed
over a row or an event (looked for every :data:`PROMPT_S` while anyone subscribes), and one at least every
:data:`FRAME_S`::

    {"ok": true, "message": "subscribed", "hello": {...}, "live_after": 41,
     "rows": [...the last RECENT_ROWS...], "events": [...the last BACKLOG_EVENTS...], "status": {...}}
    {"rows": [{"time_s": 12.08, "T2_K": 5.00002, ...}], "events": [{"seq": 42, ...}], "status": {...}}

* ``rows``: every row of the loop since the last line, with the record's fields by name (``control``
  holds the control terms' columns);
* ``events``: every event since, each with a sequence number ``seq`` counted since the daemon
  started and ``time_s``, the time of the row before it; an alarm's change carries its figures in
  ``alarm`` (name, kind, time_s, message, value). The first line's events are the recent ones;
  those up to ``live_after`` (the ``SEQ`` asked for, else the newest) happened before the
  subscription, those after it are to be acted on (a subscriber that lost its connection asks for
  what it missed);
* ``status``: what ``cryod ctl status --json`` gives, without the figures a subscriber computes
  from the rows itself (``T2_average_K``, ``line_amplitude_K``).

The loop's only part in it is appending each row and event to a bounded deque (:class:`StreamTap`,
one of its row taps). Turning them into JSON happens on the control socket's thread, once per line
for all subscribers, a few kilobytes at a time: nothing the size of an hour is ever built in the
daemon's process. A subscriber that does not read is closed once :data:`MAX_UNSENT_BYTES` wait for
it; at most :data:`MAX_SUBSCRIBERS` are served at once.

A subscriber may send lines back: ``{"report": {...}}`` says how it is doing (where it listens, what
failed); the daemon keeps the last one of each and shows them in its status (``interfaces``).
"""

from __future__ import annotations

import asyncio
import collections
import json
import logging
import math
import time
from typing import Callable

from cryod.records.columns import Event, Row

log = logging.getLogger("cryod.stream")

#: The longest time between two lines to the subscribers (s): the status goes out this often when nothing
#: else happens.
FRAME_S = 0.1
#: How often the stream's thread looks for a row or event to send while anyone subscribes (s): a reading reaches
#: a subscriber (the EPICS IOC's monitors) within this of the loop's handing it over, one row a line at the
#: loop's 80 ms. Looking is a deque's length on the socket's thread; the loop does nothing more for it.
PROMPT_S = 0.01
#: Subscribers served at once.
MAX_SUBSCRIBERS = 8
#: Events kept for a subscriber's first line and for one that reconnects.
BACKLOG_EVENTS = 200
#: Rows kept for a subscriber's first line (20 s at 80 ms: the windows of its figures).
RECENT_ROWS = 256
#: Rows and events the loop may hand over between two looks of the stream's thread (the rest are dropped,
#: and counted).
INCOMING_LIMIT = 4096
#: A subscriber with this much not yet taken by it is closed (bytes).
MAX_UNSENT_BYTES = 1_000_000
#: The longest line a subscriber may send (a report), bytes.
MAX_REPORT_BYTES = 64 * 1024

ROW_FIELDS = tuple(Row.__slots__)


class StreamTap:
    """Row tap for the stream: on the loop's thread, one deque append per row and event."""

    def __init__(self):
        self.incoming: collections.deque[Row | Event] = collections.deque()
        #: Items dropped because the stream's thread had not taken them in time.
        self.dropped = 0

    def __call__(self, item: Row | Event) -> None:
        if len(self.incoming) < INCOMING_LIMIT:
            self.incoming.append(item)
        else:
            self.dropped += 1


def row_fields(row: Row) -> dict:
    """A row as the stream sends it: the record's fields by name."""
    return {name: getattr(row, name) for name in ROW_FIELDS}


def finite_or_none(value):
    """JSON-safe copy: NaN and infinities become null (strict JSON has no NaN)."""
    if isinstance(value, dict):
        return {key: finite_or_none(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


class _Subscriber:
    def __init__(self, writer: asyncio.StreamWriter, peer: str):
        self.writer = writer
        self.peer = peer
        self.report: dict | None = None
        self.last_seq = 0
        self.since = time.time()


class StreamHub:
    """The stream's side on the control socket's thread: folds what the tap took in, serves the subscribers.

    Parameters
    ----------
    tap : StreamTap
    status : callable
        The daemon's status for the stream (no arguments; a dict).
    hello : callable
        What a subscriber is told first about the daemon (a dict: version, pid, period, ...).
    """

    def __init__(self, tap: StreamTap, status: Callable[[], dict], hello: Callable[[], dict]):
        self.tap = tap
        self.status = status
        self.hello = hello
        self.events: collections.deque[dict] = collections.deque(maxlen=BACKLOG_EVENTS)
        self.rows: collections.deque[Row] = collections.deque(maxlen=RECENT_ROWS)
        self.seq = 0
        self.subscribers: list[_Subscriber] = []
        #: Subscribers closed because they did not read.
        self.closed_slow = 0
        #: The last report of each subscriber that ended, by its pid (the last few).
        self.ended_reports: dict[int, dict] = {}
        self._last_row_s = math.nan

    # -- folding (the socket's thread) ----------------------------------------------------
    def take(self) -> tuple[list[Row], list[dict]]:
        """The rows and the events (as the stream sends them) the loop handed over since the last call."""
        rows, events = [], []
        incoming = self.tap.incoming
        while True:
            try:
                item = incoming.popleft()
            except IndexError:
                break
            if type(item) is Row:
                rows.append(item)
                self.rows.append(item)
                self._last_row_s = item.time_s
            else:
                self.seq += 1
                event = {"seq": self.seq, "kind": item.kind, "message": item.message,
                         "time_s": None if math.isnan(self._last_row_s) else self._last_row_s}
                if item.details is not None:
                    event[item.kind] = item.details
                events.append(event)
                self.events.append(event)
        return rows, events

    def last_seq_of(self, pid: int) -> int | None:
        """The last event the subscriber process ``pid`` said it had taken before it ended (None: unknown)."""
        return self.ended_reports.get(pid, {}).get("last_seq")

    def reports(self) -> list[dict]:
        """What each subscriber last said of itself, with who it is."""
        return [dict(subscriber.report, peer=subscriber.peer) for subscriber in self.subscribers
                if subscriber.report is not None]

    # -- serving ------------------------------------------------------------------------------
    async def run(self) -> None:
        """Fold and send a line as soon as there is a row or event, and every :data:`FRAME_S` at least (a task on
        the socket's event loop)."""
        last_line = time.monotonic()
        while True:
            await asyncio.sleep(PROMPT_S if self.subscribers else FRAME_S)
            now = time.monotonic()
            if self.subscribers and not self.tap.incoming and now - last_line < FRAME_S:
                continue
            last_line = now
            rows, events = self.take()
            if not self.subscribers:                # rows become JSON only for someone
                continue
            line = (json.dumps(finite_or_none({"rows": [row_fields(row) for row in rows], "events": events,
                                               "status": self.status()})) + "\n").encode("utf-8")
            for subscriber in list(self.subscribers):
                self._send(subscriber, line, events[-1]["seq"] if events else None)

    def _send(self, subscriber: _Subscriber, line: bytes, last_seq: int | None) -> None:
        transport = subscriber.writer.transport
        if transport.is_closing():
            return
        if transport.get_write_buffer_size() > MAX_UNSENT_BYTES:
            self.closed_slow += 1
            log.warning("stream: %s read nothing of the last %d bytes; closed (it may subscribe again)",
                        subscriber.peer, transport.get_write_buffer_size())
            transport.abort()
            return
        subscriber.writer.write(line)
        if last_seq is not None:
            subscriber.last_seq = last_seq

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, peer: str,
                    after: int | None) -> dict | None:
        """One subscriber, from its ``subscribe`` line to its end; the refusal to send instead, when there is
        no room."""
        if len(self.subscribers) >= MAX_SUBSCRIBERS:
            return {"ok": False, "message": f"busy: {MAX_SUBSCRIBERS} subscribers at once; try again later"}
        # what the loop handed over and the stream has not folded yet comes with the next line, as to the others
        newest = self.events[-1]["seq"] if self.events else 0
        live_after = newest if after is None or after > newest else after
        first = {"ok": True, "message": "subscribed", "hello": self.hello(), "live_after": live_after,
                 "rows": [row_fields(row) for row in self.rows], "events": list(self.events),
                 "status": self.status()}
        subscriber = _Subscriber(writer, peer)
        subscriber.last_seq = newest
        self.subscribers.append(subscriber)
        log.info("stream: %s subscribed (%d now)", peer, len(self.subscribers))
        try:
            writer.write((json.dumps(finite_or_none(first)) + "\n").encode("utf-8"))
            await self._read_reports(reader, subscriber)
        finally:
            self.subscribers.remove(subscriber)
            writer.transport.abort()
            if subscriber.report is not None and isinstance(subscriber.report.get("pid"), int):
                self.ended_reports[subscriber.report["pid"]] = subscriber.report
                while len(self.ended_reports) > MAX_SUBSCRIBERS:
                    self.ended_reports.pop(next(iter(self.ended_reports)))
            log.info("stream: %s ended (%d left)", peer, len(self.subscribers))
        return None

    async def _read_reports(self, reader: asyncio.StreamReader, subscriber: _Subscriber) -> None:
        """The subscriber's lines until it closes: each a report, the last one kept."""
        pending = bytearray()
        while True:
            chunk = await reader.read(65536)
            if not chunk:
                return
            pending += chunk
            while b"\n" in pending:
                line, _, rest = bytes(pending).partition(b"\n")
                pending = bytearray(rest)
                try:
                    report = json.loads(line)["report"]
                    if not isinstance(report, dict):
                        raise TypeError(type(report).__name__)
                except (ValueError, KeyError, TypeError) as error:
                    log.warning("stream: %s sent a line that is not a report (%s); ignored", subscriber.peer,
                                type(error).__name__)
                    continue
                subscriber.report = report
            if len(pending) > MAX_REPORT_BYTES:
                log.warning("stream: %s sent a line longer than %d bytes; closed", subscriber.peer, MAX_REPORT_BYTES)
                return


__all__ = ["StreamTap", "StreamHub", "row_fields", "finite_or_none", "FRAME_S", "PROMPT_S", "MAX_SUBSCRIBERS"]
