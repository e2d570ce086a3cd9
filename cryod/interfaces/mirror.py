"""The daemon as the interfaces process knows it: its status, its recent rows, its events, from its stream.

:class:`DaemonMirror` takes each line of the daemon's stream (:mod:`cryod.service.stream`) and keeps
what the interfaces serve: the status (with the figures ``cryod ctl status`` computes from the last
seconds of rows, ``T2_average_K`` and ``line_amplitude_K``, computed here the same way from the same
rows by a :class:`~cryod.service.live_view.LiveView`), the last hour in one-second bins
(:class:`~cryod.interfaces.history.History`), the latest row (the thermometers' resistances for the
336), and the events. Listeners are told of each new line (the web page's event streams) and of each
event to act on (the alarm hooks: only those after the subscription's ``live_after``), and of each new
row (the EPICS IOC).
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
from typing import Any, Callable

from cryod.interfaces.history import History
from cryod.records.columns import Event, Row
from cryod.service.daemon_status import DaemonStatus, status_from_json
from cryod.service.live_view import LiveView
from cryod.service.stream import ROW_FIELDS


def row_from(fields: dict) -> Row:
    """A stream's row as a :class:`Row` (nulls are NaN, as in the loop)."""
    values: dict[str, Any] = {name: (math.nan if fields.get(name) is None else fields[name]) for name in ROW_FIELDS
                              if name != "control"}
    control = {key: (math.nan if value is None else value) for key, value in (fields.get("control") or {}).items()}
    return Row(**values, control=control)


class DaemonMirror:
    """The daemon's state from its stream.

    Parameters
    ----------
    period_s : float
        The loop's period (s).
    cooler_rad_s : float
        The cooler's angular frequency (rad/s), for the line's amplitude.
    """

    def __init__(self, period_s: float, cooler_rad_s: float):
        self.view = LiveView(period_s, cooler_rad_s)
        self.history = History(self.view.line_amplitude_K, self.view.heater_mean_W)
        #: The status as the stream's last line gave it.
        self.stream_status = DaemonStatus(waiting_for="the interfaces process is not connected to the daemon yet")
        self.hello: dict = {}
        self.connected = False
        #: The sequence number of the last event taken.
        self.last_seq = 0
        #: Set at each new line (and replaced): what an event stream waits on.
        self.changed = asyncio.Event()
        self._on_event: list[Callable[[dict], None]] = []
        self._on_row: list[Callable[[Row], None]] = []
        self.view.attach_timing(lambda: dataclasses.asdict(self.stream_status.loop.timing))
        self.view.attach_alarms(lambda: [alarm["name"] for alarm in self.stream_status.alarms])

    def on_event(self, listener: Callable[[dict], None]) -> None:
        """Call ``listener(event)`` for each event to act on (after the subscription's ``live_after``)."""
        self._on_event.append(listener)

    def on_row(self, listener: Callable[[Row], None]) -> None:
        """Call ``listener(row)`` for each new row of the loop, in order (the EPICS IOC's readings, each with its
        own sample instant)."""
        self._on_row.append(listener)

    # -- the stream's lines ------------------------------------------------------------------
    def first(self, line: dict) -> None:
        """The subscription's first line: who the daemon is, the recent rows and events, the status."""
        self.hello = line.get("hello") or {}
        live_after = int(line.get("live_after") or 0)
        self._rows(line.get("rows") or [], first=True)
        for event in line.get("events") or []:
            self.history.add_event(event)
            if event["seq"] > self.last_seq:
                self.view(Event(event["kind"], event["message"]))     # faults since the start, for the metrics
                if event["seq"] > live_after:
                    self._act_on(event)
        self.last_seq = max(self.last_seq, live_after)
        self.connected = True
        self._status(line.get("status"))

    def frame(self, line: dict) -> None:
        """One more line of the stream."""
        self._rows(line.get("rows") or [])
        for event in line.get("events") or []:
            self.history.add_event(event)
            if event["seq"] > self.last_seq:
                self.view(Event(event["kind"], event["message"]))
                self._act_on(event)
        self._status(line.get("status"))

    def lost(self) -> None:
        """The connection to the daemon ended: what is served says so until it is back."""
        self.connected = False
        self.stream_status = DaemonStatus(waiting_for="the interfaces process lost the daemon's stream; "
                                                      "connecting again")
        self._changed()

    def _rows(self, rows: list[dict], first: bool = False) -> None:
        last = self.history.bins[-1]["time_s"] if first and self.history.bins else None
        taken = self.view.latest_row()
        for fields in rows:
            row = row_from(fields)
            if first and taken is not None and row.time_s <= taken.time_s:
                continue                        # after a reconnection: rows already taken
            if last is not None and row.time_s < last:
                continue
            self.view(row)
            self.history.add_row(row)
            for listener in self._on_row:
                listener(row)

    def _act_on(self, event: dict) -> None:
        self.last_seq = event["seq"]
        for listener in self._on_event:
            listener(event)

    def _status(self, data: dict | None) -> None:
        if isinstance(data, dict):
            self.stream_status = status_from_json(data)
        self._changed()

    def _changed(self) -> None:
        self.changed.set()
        self.changed = asyncio.Event()

    # -- what the interfaces serve -------------------------------------------------------------
    def status(self) -> DaemonStatus:
        """What ``cryod ctl status`` says: the stream's status with the figures of the recent rows and the
        thermometers' resistances of the latest."""
        status = self.stream_status
        if not self.connected or status.waiting_for is not None:
            return status
        row = self.view.latest_row()
        return dataclasses.replace(status, recent=self.view.recent(),
                                   flange_ohm=None if row is None else row.T2_ohm,
                                   ptc_stage_ohm=None if row is None else row.T5_ohm)

    def latest_row(self) -> Row | None:
        return self.view.latest_row()

    @property
    def time_s(self) -> float:
        """The daemon's clock as of the last row (s), NaN before the first."""
        row = self.view.latest_row()
        return math.nan if row is None else row.time_s


__all__ = ["DaemonMirror", "row_from"]
