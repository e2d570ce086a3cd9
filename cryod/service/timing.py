"""Lateness and overrun statistics of the control loop, cheap enough for the hot path.

Lateness (how long after its deadline a tick started) goes into fixed 10 µs
bins, so recording is one list increment and percentiles cost nothing until
asked for, however long the daemon runs.

Examples
--------
>>> stats = LoopTiming(period_s=0.08)
>>> for lateness in (0.0001, 0.0002, 0.0003):
...     stats.record_tick(lateness)
>>> stats.summary()["lateness_ms_max"]
0.3
"""

from __future__ import annotations

import dataclasses

from cryod.service.daemon_status import TimingFigures

BIN_S = 10e-6


class LoopTiming:
    """Tick lateness histogram, overrun counts and the current overrun streak.

    Parameters
    ----------
    period_s : float
        Loop period; lateness is binned up to one period, beyond that in a last bin.
    """

    def __init__(self, period_s: float):
        self.period_s = period_s
        self._bins = [0] * (int(period_s / BIN_S) + 2)
        self.ticks = 0
        self.overruns = 0
        self.missed_deadlines = 0
        self.overrun_streak = 0
        #: Cycles in a row that ended before the next deadline.
        self.on_time_streak = 0
        #: Cycles that ended late while the heater was off waiting for valid readings (instruments timing
        #: out during a recovery): not overruns.
        self.waiting_cycles = 0
        self.lateness_max_s = 0.0
        self.gc_longest_s = 0.0

    def record_tick(self, lateness_s: float) -> None:
        """One tick started ``lateness_s`` after its deadline."""
        self.ticks += 1
        if lateness_s < 0.0:
            lateness_s = 0.0
        index = int(lateness_s / BIN_S)
        bins = self._bins
        bins[index if index < len(bins) else -1] += 1
        if lateness_s > self.lateness_max_s:
            self.lateness_max_s = lateness_s

    def record_cycle_end(self, missed: int) -> None:
        """The cycle ended ``missed`` deadlines late (0: in time)."""
        if missed > 0:
            self.overruns += 1
            self.missed_deadlines += missed
            self.overrun_streak += 1
            self.on_time_streak = 0
        else:
            self.overrun_streak = 0
            self.on_time_streak += 1

    def percentile_s(self, fraction: float) -> float:
        """Lateness (s) below which ``fraction`` of the ticks started (bin upper edge)."""
        if self.ticks == 0:
            return 0.0
        target = fraction * self.ticks
        running = 0
        for index, count in enumerate(self._bins):
            running += count
            if running >= target:
                return min((index + 1) * BIN_S, self.lateness_max_s)
        return self.lateness_max_s

    def figures(self) -> TimingFigures:
        """Counts and lateness percentiles in ms, as the status gives them."""
        return TimingFigures(ticks=self.ticks, overruns=self.overruns, missed_deadlines=self.missed_deadlines,
                             late_cycles_waiting_for_instruments=self.waiting_cycles,
                             lateness_ms_p50=round(self.percentile_s(0.50) * 1e3, 3),
                             lateness_ms_p99=round(self.percentile_s(0.99) * 1e3, 3),
                             lateness_ms_max=round(self.lateness_max_s * 1e3, 3),
                             gc_ms_max=round(self.gc_longest_s * 1e3, 3))

    def summary(self) -> dict:
        """:meth:`figures` by name (the ``--json`` summary, the status line)."""
        return dataclasses.asdict(self.figures())
