"""The last hour of the loop in one-second bins, for the web page: kept off the loop's thread.

:class:`RecentRows` is one more listener of the loop's rows and events (a row tap, like the data
log): on the loop thread it only appends a reference to a short deque. :class:`History`, on the web
interface's thread, takes what came since its last look and folds it into one-second bins: the
band (least and most) and mean of T2, T5 and the heater, PI's part, the feedforward waveform's band,
the setpoint and the state; the last :data:`SPAN_S` are kept. Events (faults, commands, notes)
are kept with the time of the row before them and a sequence number.

Examples
--------
>>> from cryod.records.columns import Row
>>> recent, history = RecentRows(), History()
>>> for tick in range(30):
...     recent(Row(time_s=0.08 * tick, lateness_ms=0.1, state="closed", T2_K=5.0 + 1e-4 * (tick % 3), T5_K=3.4, heater_W=0.1,
...                setpoint_K=5.0, control={"pi_proportional_W": 0.02, "pi_integral_W": 0.08}))
>>> bins = history.take(recent)
>>> len(bins), bins[0]["T2_max_K"] - bins[0]["T2_min_K"] > 1.9e-4, bins[0]["pi_W"]
(2, True, 0.1)
"""

from __future__ import annotations

import collections
import math

from cryod.records.columns import Event, Row

#: Width of a bin, s.
BIN_S = 1.0
#: Bins kept: one hour.
SPAN_S = 3600.0
#: Rows held for the web interface between two of its looks (20 s of rows at 80 ms).
RECENT_ROWS = 256
#: Events kept.
EVENTS_KEPT = 200


class RecentRows:
    """Row tap: the latest rows and events, for a reader on another thread (deque appends are atomic)."""

    def __init__(self):
        self.rows: collections.deque = collections.deque(maxlen=RECENT_ROWS)
        self.events: collections.deque = collections.deque(maxlen=EVENTS_KEPT)

    def __call__(self, item: Row | Event) -> None:
        if type(item) is Row:
            self.rows.append(item)
        else:
            self.events.append(item)


def _finite(values: list[float]) -> list[float]:
    return [value for value in values if value == value and value not in (math.inf, -math.inf)]


class _Bin:
    """One second's rows, folded as they come."""

    def __init__(self, start_s: float):
        self.start_s = start_s
        self.flange: list[float] = []
        self.stage: list[float] = []
        self.heater: list[float] = []
        self.pi: list[float] = []
        self.feedforward: list[float] = []
        self.setpoint = math.nan
        self.limit = math.nan
        self.state = ""

    def add(self, row: Row) -> None:
        self.flange.append(row.T2_K)
        self.stage.append(row.T5_K)
        self.heater.append(row.heater_W)
        control = row.control or {}
        if "pi_proportional_W" in control:
            self.pi.append(control.get("pi_proportional_W", 0.0) + control.get("pi_integral_W", 0.0))
        if "ff_W" in control:
            self.feedforward.append(control["ff_W"])
        self.limit = control.get("ff_limit_K", self.limit)
        self.setpoint = row.setpoint_K
        self.state = str(row.state)

    def summary(self, line_amplitude_K: float) -> dict:
        """The bin as the page draws it; absent values are None."""
        def band(name: str, values: list[float]) -> dict:
            values = _finite(values)
            if not values:
                return {f"{name}_min": None, f"{name}_max": None, f"{name}_mean": None}
            return {f"{name}_min": min(values), f"{name}_max": max(values), f"{name}_mean": sum(values) / len(values)}

        flange, stage, heater = band("T2", self.flange), band("T5", self.stage), band("heater", self.heater)
        pi, feedforward = _finite(self.pi), _finite(self.feedforward)
        return {"time_s": self.start_s,
                "T2_min_K": flange["T2_min"], "T2_max_K": flange["T2_max"], "T2_mean_K": flange["T2_mean"],
                "T5_min_K": stage["T5_min"], "T5_max_K": stage["T5_max"], "T5_mean_K": stage["T5_mean"],
                "heater_min_W": heater["heater_min"], "heater_max_W": heater["heater_max"],
                "heater_mean_W": heater["heater_mean"],
                "pi_W": sum(pi) / len(pi) if pi else None,
                "ff_min_W": min(feedforward) if feedforward else None,
                "ff_max_W": max(feedforward) if feedforward else None,
                "setpoint_K": self.setpoint if math.isfinite(self.setpoint) else None,
                "line_amplitude_K": line_amplitude_K if math.isfinite(line_amplitude_K) else None,
                "line_limit_K": self.limit if math.isfinite(self.limit) else None,
                "state": self.state}


class History:
    """One-second bins of the last hour and the recent events, fed from :class:`RecentRows`."""

    def __init__(self):
        self.bins: collections.deque = collections.deque(maxlen=int(SPAN_S / BIN_S))
        self.events: collections.deque = collections.deque(maxlen=EVENTS_KEPT)
        self._open: _Bin | None = None
        self._last_time_s = math.nan
        self._events_seen = 0

    def take(self, recent: RecentRows, line_amplitude_K=lambda: math.nan) -> list[dict]:
        """Fold in the rows and events that came since the last call; the bins completed by them.

        ``line_amplitude_K`` (a callable) gives the cooler line's amplitude now, written into
        each bin as it is completed.
        """
        completed = []
        while True:
            try:
                row = recent.rows.popleft()
            except IndexError:
                break
            start = math.floor(row.time_s / BIN_S) * BIN_S
            if self._open is not None and start != self._open.start_s:
                completed.append(self._open.summary(line_amplitude_K()))
                self._open = None
            if self._open is None:
                self._open = _Bin(start)
            self._open.add(row)
            self._last_time_s = row.time_s
        while True:
            try:
                event = recent.events.popleft()
            except IndexError:
                break
            self._events_seen += 1
            self.events.append({"seq": self._events_seen, "kind": event.kind, "message": event.message,
                                "time_s": None if math.isnan(self._last_time_s) else self._last_time_s})
        self.bins.extend(completed)
        return completed

    def since(self, time_s: float | None) -> list[dict]:
        """The bins that start after ``time_s`` (all of them for None)."""
        return [item for item in self.bins if time_s is None or item["time_s"] > time_s]
