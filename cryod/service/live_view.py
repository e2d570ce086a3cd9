"""The daemon's latest state for the eyes of the operator and the lab's monitoring.

:class:`LiveView` is one more listener of the loop's rows and events (a row tap,
like the data log). On the loop thread it only keeps references and writes three
numbers into a ring, so it costs the 80 ms cycle nothing worth measuring; the
figures are computed when someone asks (:meth:`LiveView.snapshot`): the status
line on the terminal (:mod:`cryod.service.status_line`) and ``cryod ctl status``
in the daemon; the interfaces process keeps one of its own, fed by the daemon's
stream, for the web page, the 336 and the Prometheus endpoint
(:mod:`cryod.interfaces.metrics`).

The cooler line's amplitude on T2 is its whole periodic part, harmonics 1 to 6
together, as everywhere in cryod: the feedforward's own estimate (``ff_line_K``)
when the feedforward runs, otherwise a least-squares fit of those harmonics of
the cooler's frequency over the last :data:`LINE_WINDOW_S` of T2 readings.

Examples
--------
>>> import math
>>> from cryod.records.columns import Row
>>> view = LiveView(period_s=0.08, line_rad_s=10.83)
>>> for tick in range(400):
...     t = 0.08 * tick
...     view(Row(time_s=t, lateness_ms=0.1, state="closed", T2_K=5.0 + 0.0015 * math.sin(10.83 * t),
...              T5_K=3.4, heater_W=0.113, setpoint_K=5.0, T2_sample_s=t))
>>> snapshot = view.snapshot()
>>> snapshot["state"], round(snapshot["line_amplitude_K"] * 1e3, 2), round(snapshot["elapsed_s"], 2)
('closed', 1.5, 31.92)
"""

from __future__ import annotations

import math
import threading

import numpy as np

from cryod.cooler.line_fit import fit_line
from cryod.cooler.periodic import PERIODIC_HARMONICS
from cryod.records.columns import Event, Row
from cryod.service.daemon_status import RecentFigures

#: T2 readings kept for the line's amplitude when the feedforward does not estimate it (s).
LINE_WINDOW_S = 20.0
#: T2 is averaged over this much of the recent past (s): about 17 cooler periods, so the line
#: (1.75 mK at most) leaves less than 20 µK in the average.
AVERAGE_WINDOW_S = 10.0
#: The harmonics of the cooler's frequency the line is made of (the measure of ``ptc_periodic_amplitude_K``).
LINE_HARMONICS = tuple(range(1, PERIODIC_HARMONICS + 1))
#: The heater's level is its power averaged over this many whole cooler cycles: what the setpoint costs,
#: without the feedforward's waveform (which averages to nothing over whole cycles).
HEATER_CYCLES = 10


class LiveView:
    """Latest row, fault count and a short ring of T2 readings, kept for on-demand figures.

    Parameters
    ----------
    period_s : float
        Loop period (s); sizes the ring.
    line_rad_s : float
        The cooler's angular frequency (rad/s) for the line's amplitude.
    timing : callable, optional
        Returns the loop's timing summary (``LoopTiming.summary``); attached later with
        :meth:`attach_timing` when the loop exists after the view.
    """

    def __init__(self, period_s: float, line_rad_s: float, timing=None):
        self.period_s = float(period_s)
        self.line_rad_s = float(line_rad_s)
        self._timing = timing
        self._alarms = None
        size = max(int(LINE_WINDOW_S / self.period_s), 16)
        # plain lists: the loop writes one element a tick (cheaper than a numpy element); readers copy them to arrays
        self._times = [math.nan] * size
        self._flange = [math.nan] * size
        self._heater = [math.nan] * size
        self._next = 0
        self._row: Row | None = None
        self._first_time_s: float | None = None
        self._faults: dict[str, int] = {}
        self._last_fault: str | None = None
        self._events = 0
        self._lock = threading.Lock()       # only for the fault counts (events are rare)

    def attach_timing(self, timing) -> None:
        """Give the loop's timing summary (a callable returning a dict)."""
        self._timing = timing

    def attach_alarms(self, raised) -> None:
        """Give the alarms raised now (a callable returning their names), for the snapshot's ``alarms``."""
        self._alarms = raised

    # -- the tap (loop thread) ------------------------------------------------------
    def __call__(self, item: Row | Event) -> None:
        if type(item) is Row:
            if self._first_time_s is None:
                self._first_time_s = item.time_s
            index = self._next % len(self._times)
            sample = item.T2_sample_s
            self._times[index] = sample if sample == sample else item.time_s
            self._flange[index] = item.T2_K
            self._heater[index] = item.heater_W
            self._next += 1
            self._row = item
        else:
            self._events += 1
            if item.kind == "fault":
                cause = item.message.split(":", 1)[0].strip() or "unknown"
                with self._lock:
                    self._faults[cause] = self._faults.get(cause, 0) + 1
                    self._last_fault = item.message

    # -- readers (any thread) -----------------------------------------------------------
    def line_amplitude_K(self) -> float:
        """The cooler line's amplitude on T2 now (K): its whole periodic part, harmonics 1-6 together (the
        measure of ``ptc_periodic_amplitude_K`` and of the feedforward's limit); NaN until there is enough."""
        row = self._row
        if row is not None:
            estimate = row.control.get("ff_line_K", math.nan)
            if estimate == estimate and row.control.get("ff_scale", 0.0):
                return float(estimate)
        times, flange = np.array(self._times), np.array(self._flange)
        usable = np.isfinite(times) & np.isfinite(flange)
        if usable.sum() < max(times.size // 2, 16):
            return math.nan
        fitted = fit_line(times[usable], flange[usable], self.line_rad_s, orders=LINE_HARMONICS)
        return float(np.sqrt(np.sum(np.asarray(fitted.amplitude) ** 2)))

    def flange_average_K(self) -> float:
        """T2 averaged over the last :data:`AVERAGE_WINDOW_S` (K), NaN until there is that much."""
        times, flange = np.array(self._times), np.array(self._flange)
        usable = np.isfinite(times) & np.isfinite(flange)
        if not usable.any():
            return math.nan
        times, flange = times[usable], flange[usable]
        recent = times >= times.max() - AVERAGE_WINDOW_S
        if times.max() - times[recent].min() < AVERAGE_WINDOW_S - 2 * self.period_s:
            return math.nan
        return float(np.mean(flange[recent]))

    def heater_mean_W(self) -> float:
        """The heater power averaged over the last :data:`HEATER_CYCLES` whole cooler cycles (W), NaN until
        there are that many."""
        times, heater = np.array(self._times), np.array(self._heater)
        usable = np.isfinite(times) & np.isfinite(heater)
        if not usable.any():
            return math.nan
        times, heater = times[usable], heater[usable]
        span_s = HEATER_CYCLES * 2.0 * math.pi / self.line_rad_s
        recent = times > times.max() - span_s
        if times.max() - times[recent].min() < span_s - 2.0 * self.period_s:
            return math.nan
        return float(np.mean(heater[recent]))

    def recent(self) -> RecentFigures:
        """The figures of the recent past the status gives: T2's 10 s average, the line's amplitude, the heater's
        level."""
        return RecentFigures(self.flange_average_K(), self.line_amplitude_K(), self.heater_mean_W())

    def latest_row(self) -> Row | None:
        """The last row the loop made (None before the first)."""
        return self._row

    def faults(self) -> dict[str, int]:
        """Faults seen since start, by cause."""
        with self._lock:
            return dict(self._faults)

    def snapshot(self) -> dict:
        """The figures of the last row, with units in the keys; empty values are NaN or None.

        Keys: ``time_s`` (the clock time of the last tick), ``elapsed_s`` (since the first
        row), ``state``, ``T2_K``, ``T2_average_K`` (over the last :data:`AVERAGE_WINDOW_S`),
        ``T5_K``, ``setpoint_K``, ``error_K`` (T2 minus the setpoint), ``heater_W``,
        ``line_amplitude_K``, ``lateness_ms``, ``faults`` (count by cause), ``last_fault``,
        ``ticks``, ``overruns``, ``T2_ohm``, ``T5_ohm`` (the thermometers' resistances), ``heater_mean_W`` (the
        heater's power over the last whole cooler cycles), ``pi_W``
        (PI's part of the heater power), ``ff_W`` (the feedforward's), ``line_limit_K`` (the least line
        any heater waveform can leave at this setpoint), ``alarms`` (the names of the alarms raised or latched).
        """
        snapshot = self._figures()
        snapshot["alarms"] = self._alarms() if self._alarms is not None else []
        return snapshot

    def _figures(self) -> dict:
        row = self._row
        nan = math.nan
        if row is None:
            return {"time_s": nan, "elapsed_s": 0.0, "state": "starting", "T2_K": nan, "T2_average_K": nan,
                    "T5_K": nan,
                    "setpoint_K": nan, "error_K": nan, "heater_W": nan, "line_amplitude_K": nan,
                    "lateness_ms": nan, "faults": self.faults(), "last_fault": self._last_fault,
                    "ticks": 0, "overruns": 0, "T2_ohm": nan, "T5_ohm": nan, "heater_mean_W": nan, "pi_W": nan,
                    "ff_W": nan,
                    "line_limit_K": nan}
        timing = self._timing() if self._timing is not None else {}
        control = row.control or {}
        first = self._first_time_s if self._first_time_s is not None else row.time_s
        return {"time_s": row.time_s, "elapsed_s": row.time_s - first,
                "state": str(row.state), "T2_K": row.T2_K, "T2_average_K": self.flange_average_K(),
                "T5_K": row.T5_K, "setpoint_K": row.setpoint_K,
                "error_K": row.T2_K - row.setpoint_K, "heater_W": row.heater_W,
                "line_amplitude_K": self.line_amplitude_K(), "lateness_ms": row.lateness_ms,
                "faults": self.faults(), "last_fault": self._last_fault,
                "ticks": timing.get("ticks", self._next), "overruns": timing.get("overruns", 0),
                "T2_ohm": row.T2_ohm, "T5_ohm": row.T5_ohm, "heater_mean_W": self.heater_mean_W(),
                "pi_W": (control["pi_proportional_W"] + control.get("pi_integral_W", 0.0)
                         if "pi_proportional_W" in control else nan),
                "ff_W": control.get("ff_W", nan), "line_limit_K": control.get("ff_limit_K", nan)}
