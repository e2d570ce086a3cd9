"""The stretch of a long record that ``cryod analyze`` analyses.

Every candidate cause is fitted by replaying the record tens of times, so the
analysis costs time and memory in proportion to the record's length (about
10 s of CPU and 80 MB per hour of 12.5 Hz record). What names a cause is the
cooler's line, seen everywhere, and how the temperatures follow the heater's
changes; hours of steady regulation add little to either. A record longer than
:data:`ANALYSIS_WINDOW_S` is therefore analysed on the stretch of that length
where the heater moves most: where the variance of its 10 s means (the slow
changes, not the line it may be playing) is largest, over the rows with both
temperatures. Equal stretches: the earliest. ``cryod analyze --max-duration 0``
analyses the whole record.

Examples
--------
>>> import numpy as np
>>> time_s = np.arange(0.0, 6 * 3600.0, 0.08)
>>> heater_w = np.where((time_s > 14000.0) & (time_s < 15000.0), 0.1, 0.05)    # a step up and down at 4 h
>>> start, stop = busiest_stretch(time_s, heater_w, 7200.0)
>>> float(time_s[start]) <= 14000.0 and float(time_s[stop - 1]) >= 15000.0
True
"""

from __future__ import annotations

import numpy as np

#: Longest stretch analysed by default (s): two hours.
ANALYSIS_WINDOW_S = 7200.0
#: The heater's movement is judged on its means over this length (s).
HEATER_MEAN_S = 10.0
#: Stretches tried start this far apart (s).
STRETCH_STEP_S = 60.0


def busiest_stretch(time_s, heater_w, length_s: float, valid=None) -> tuple[int, int]:
    """The rows ``[start, stop)`` of the stretch of ``length_s`` where the heater moves most.

    Parameters
    ----------
    time_s : array_like
        Sample instants (s), increasing.
    heater_w : array_like
        Heater power (W).
    length_s : float
        Length of the stretch (s); the whole record if it is not longer.
    valid : array_like of bool, optional
        Rows that count (both temperatures present); default all.

    Returns
    -------
    (int, int)
        Start and stop row indices.
    """
    time_s = np.asarray(time_s, dtype=float)
    heater_w = np.asarray(heater_w, dtype=float)
    if time_s.size == 0 or time_s[-1] - time_s[0] <= length_s:
        return 0, int(time_s.size)
    valid = np.ones(time_s.size, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    means_per_stretch = int(round(length_s / HEATER_MEAN_S))
    step = max(int(round(STRETCH_STEP_S / HEATER_MEAN_S)), 1)
    bins = np.floor((time_s[valid] - time_s[0]) / HEATER_MEAN_S).astype(np.int64)
    count = np.bincount(bins, minlength=means_per_stretch + 1).astype(float)
    total = np.bincount(bins, weights=heater_w[valid], minlength=count.size)
    present = count > 0.0
    mean = np.divide(total, count, out=np.zeros_like(total), where=present)
    # per stretch of means: their number, sum and sum of squares, from running sums
    sums = [np.concatenate([[0.0], np.cumsum(values)]) for values in (present * 1.0, mean, mean ** 2)]
    last = max(count.size - means_per_stretch, 0)
    starts = np.unique(np.append(np.arange(0, last + 1, step), last))
    stops = np.minimum(starts + means_per_stretch, count.size)
    number, first, second = (running[stops] - running[starts] for running in sums)
    with np.errstate(invalid="ignore", divide="ignore"):
        variance = np.where(number > 1, second / number - (first / number) ** 2, -1.0)
    # the earliest of the stretches equal to the best but for rounding
    tolerance = 1e-9 * float(np.max(np.where(number > 0, second / np.maximum(number, 1.0), 0.0)))
    best = int(starts[int(np.flatnonzero(variance >= variance.max() - tolerance)[0])])
    start_s = time_s[0] + best * HEATER_MEAN_S
    start = int(np.searchsorted(time_s, start_s, side="left"))
    stop = int(np.searchsorted(time_s, start_s + length_s, side="right"))
    return start, stop


__all__ = ["ANALYSIS_WINDOW_S", "busiest_stretch"]
