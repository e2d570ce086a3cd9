"""Which rows of a record show the cryostat settled, and the clean stretches a spectrum may use.

A record starts with the loop holding the heater off, then T2 on its way to the setpoint: a
transient of tens of mK that buries the cooler's line in any spectrum that includes it. Overruns
(deadlines skipped: the readings are no longer evenly spaced) and faults break the record too.
This module says where the start-up ends and cuts the rest into stretches without those, for
the quick look's spectrum and its marks.

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 600.0, 0.08)
>>> flange = 5.0 - 0.05 * np.exp(-t / 40.0) + 0.001 * np.sin(10.83 * t)
>>> end = startup_end_s(t, flange, np.full(t.size, 5.0))
>>> round(end)
254
>>> stretches = clean_stretches(t, t >= end, breaks_s=[300.0], period_s=0.08)
>>> [(round(t[start]), round(t[stop - 1])) for start, stop in stretches]
[(254, 300), (300, 600)]
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

#: T2 is averaged over this long to judge whether it has settled (s): about 17 cooler periods, so the
#: cooler's line leaves less than 20 µK in the average.
SETTLING_AVERAGE_S = 10.0
#: T2 has settled once its average is this close to the setpoint (K): half the 0.2 mK a gas-thermometry run
#: needs the flange held to.
SETTLED_K = 1e-4
#: ... and stays so for this long (s): a T2 that crosses the setpoint on its way to an overshoot has not settled.
SETTLED_HOLD_S = 60.0


def _samples(time_s: np.ndarray, span_s: float) -> int:
    interval = float(np.median(np.diff(time_s))) if time_s.size > 1 else 1.0
    return max(int(round(span_s / interval)), 1) if interval > 0 else 1


def settled(time_s, flange_K, setpoint_K, tolerance_K: float = SETTLED_K) -> np.ndarray:
    """Rows where the loop regulates and T2 averaged over :data:`SETTLING_AVERAGE_S` is within ``tolerance_K``
    of the setpoint (boolean mask)."""
    time_s, flange_K, setpoint_K = (np.asarray(values, dtype=float) for values in (time_s, flange_K, setpoint_K))
    error = flange_K - setpoint_K
    regulated = np.isfinite(error)
    if not regulated.any():
        return regulated
    average = ndimage.uniform_filter1d(np.where(regulated, error, 0.0), _samples(time_s, SETTLING_AVERAGE_S),
                                       mode="nearest")
    return regulated & (np.abs(average) <= tolerance_K)


def startup_end_s(time_s, flange_K, setpoint_K, tolerance_K: float = SETTLED_K) -> float | None:
    """When the start-up ends: the first row from which the loop regulates a flange that stays settled for
    :data:`SETTLED_HOLD_S` (or to the record's end), so an overshoot past the setpoint is part of it (s).

    None for a record in which the loop never regulates (an open-loop experiment: no start-up to
    leave out); a record that never settles is start-up throughout (its last instant is returned).
    """
    time_s = np.asarray(time_s, dtype=float)
    if not np.isfinite(np.asarray(setpoint_K, dtype=float)).any():
        return None
    mask = settled(time_s, flange_K, setpoint_K, tolerance_K)
    for start, stop in clean_stretches(time_s, mask, period_s=np.inf):
        if time_s[stop - 1] - time_s[start] >= SETTLED_HOLD_S or stop == time_s.size:
            return float(time_s[start])
    return float(time_s[-1])


def clean_stretches(time_s, usable, breaks_s=(), period_s: float | None = None) -> list[tuple[int, int]]:
    """Runs of usable rows (``start``, ``stop`` indices) without a gap, cut at every instant of ``breaks_s``.

    Parameters
    ----------
    time_s : array_like
        Row instants (s).
    usable : array_like of bool
        Rows that may be used (settled, both temperatures read).
    breaks_s : iterable of float
        Instants that cut a stretch (overruns, faults): the row at or after each is a new stretch's first.
    period_s : float, optional
        The loop period; rows further apart than 1.5 periods (a deadline skipped) cut too. Default:
        the median interval.
    """
    time_s = np.asarray(time_s, dtype=float)
    usable = np.asarray(usable, dtype=bool) & np.isfinite(time_s)
    if time_s.size == 0:
        return []
    period = float(np.median(np.diff(time_s))) if period_s is None and time_s.size > 1 else (period_s or 1.0)
    cut = np.zeros(time_s.size, dtype=bool)
    cut[1:] = np.diff(time_s) > 1.5 * period
    for instant in breaks_s:
        index = int(np.searchsorted(time_s, instant, side="left"))
        if index < time_s.size:
            cut[index] = True
    starts = np.flatnonzero(usable & (np.r_[True, ~usable[:-1]] | cut))
    ends = np.flatnonzero(~usable | cut)
    stops = [int(ends[position]) if position < ends.size else time_s.size
             for position in np.searchsorted(ends, starts, side="right")]
    return [(int(start), stop) for start, stop in zip(starts, stops)]


def settled_stretches(time_s, flange_K, setpoint_K, breaks_s=(),
                      period_s: float | None = None) -> list[tuple[int, int]]:
    """The stretches a spectrum of T2 may use: after the start-up, settled, with both ends inside a run without a
    gap or a break (overruns, faults). A record in which the loop never regulates: every row with a T2 reading."""
    time_s, flange_K = np.asarray(time_s, dtype=float), np.asarray(flange_K, dtype=float)
    usable = np.isfinite(flange_K)
    end = startup_end_s(time_s, flange_K, setpoint_K)
    if end is not None:
        usable &= settled(time_s, flange_K, setpoint_K) & (time_s >= end)
    return clean_stretches(time_s, usable, breaks_s, period_s)


__all__ = ["SETTLED_HOLD_S", "SETTLED_K", "SETTLING_AVERAGE_S", "clean_stretches", "settled", "settled_stretches",
           "startup_end_s"]
