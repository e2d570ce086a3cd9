"""The last hour of the loop in one-second bins, for the web page, folded in the interfaces process.

:class:`History` takes the daemon's rows as its stream brings them (:mod:`cryod.service.stream`)
and folds them into one-second bins: the band (least and most) and mean of T2, T5 and the heater,
the heater's level (its mean over the last whole cooler cycles, which a second's mean is not: a
second holds 1.7 cycles of the feedforward's waveform, so its mean swings by tens of milliwatts with
the phase it starts at), PI's part, the feedforward waveform's band, the setpoint and the state; the
cooler line and its limit; the last :data:`SPAN_S` are
kept. Events (faults, commands, notes) are kept as the stream numbers them, with the time of the
row before them. None of this touches the daemon's process.

Examples
--------
>>> from cryod.records.columns import Row
>>> history = History()
>>> for tick in range(30):
...     _ = history.add_row(Row(time_s=0.08 * tick, lateness_ms=0.1, state="closed", T2_K=5.0 + 1e-4 * (tick % 3),
...                             T5_K=3.4, heater_W=0.1, setpoint_K=5.0,
...                             control={"pi_proportional_W": 0.02, "pi_integral_W": 0.08}))
>>> bins = list(history.bins)
>>> len(bins), bins[0]["T2_max_K"] - bins[0]["T2_min_K"] > 1.9e-4, bins[0]["pi_W"]
(2, True, 0.1)
"""

from __future__ import annotations

import collections
import math

from cryod.records.columns import Row

#: Width of a bin, s.
BIN_S = 1.0
#: Bins kept: one hour.
SPAN_S = 3600.0
#: Events kept.
EVENTS_KEPT = 200


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

    def summary(self, line_amplitude_K: float, heater_level_W: float) -> dict:
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
                "heater_level_W": heater_level_W if math.isfinite(heater_level_W) else None,
                "pi_W": sum(pi) / len(pi) if pi else None,
                "ff_min_W": min(feedforward) if feedforward else None,
                "ff_max_W": max(feedforward) if feedforward else None,
                "setpoint_K": self.setpoint if math.isfinite(self.setpoint) else None,
                "line_amplitude_K": line_amplitude_K if math.isfinite(line_amplitude_K) else None,
                "line_limit_K": self.limit if math.isfinite(self.limit) else None,
                "state": self.state}


class History:
    """One-second bins of the last hour and the recent events, fed row by row and event by event.

    Parameters
    ----------
    line_amplitude_K : callable, optional
        The cooler line's amplitude on T2 now (K), written into each bin as it is completed.
    heater_level_W : callable, optional
        The heater's mean over the last whole cooler cycles now (W), written into each bin as it is
        completed (``heater_level_W``).
    """

    def __init__(self, line_amplitude_K=lambda: math.nan, heater_level_W=lambda: math.nan):
        self.line_amplitude_K = line_amplitude_K
        self.heater_level_W = heater_level_W
        self.bins: collections.deque = collections.deque(maxlen=int(SPAN_S / BIN_S))
        self.events: collections.deque = collections.deque(maxlen=EVENTS_KEPT)
        self._open: _Bin | None = None

    def add_row(self, row: Row) -> dict | None:
        """Fold in one row; the bin it completed, if any."""
        start = math.floor(row.time_s / BIN_S) * BIN_S
        completed = None
        if self._open is not None and start != self._open.start_s:
            completed = self._open.summary(self.line_amplitude_K(), self.heater_level_W())
            self.bins.append(completed)
            self._open = None
        if self._open is None:
            self._open = _Bin(start)
        self._open.add(row)
        return completed

    def add_event(self, event: dict) -> None:
        """Keep one event of the stream (``seq``, ``kind``, ``message``, ``time_s``)."""
        if not self.events or event["seq"] > self.events[-1]["seq"]:
            self.events.append({key: event[key] for key in ("seq", "kind", "message", "time_s")})

    def since(self, time_s: float | None) -> list[dict]:
        """The bins that start after ``time_s`` (all of them for None)."""
        return [item for item in self.bins if time_s is None or item["time_s"] > time_s]
