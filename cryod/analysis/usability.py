"""Whether a record can be analysed at all, and if not, what it is missing.

:func:`check_usable` is the first thing the analysis does with a record's data
(the reader has already refused what cannot be read: a missing column, a
record too short). It refuses, with a message a lab user can act on:

* instants that do not increase (two runs in one file, a clock reset);
* too many rows without a temperature (:data:`LEAST_VALID_FRACTION` of the rows
  must have both T2 and T5);
* no cooler line in T5 (the cooler stopped, T5 not on the second stage): the
  replay takes the line from T5, so it must stand at least
  :data:`LEAST_LINE_OVER_NOISE` times above T5's noise;
* a heater saturated throughout (a setpoint out of reach: the regulator held
  the heater at its limit, or at 0 W, in every row): the heater paths, which
  every cause but the cooler's own changes, are then never seen.

Examples
--------
>>> import numpy as np
>>> from cryod.analysis.record_data import RecordData
>>> t = np.arange(0.0, 300.0, 0.08)
>>> noise = np.random.default_rng(1).normal(0.0, 3e-4, t.size)
>>> data = RecordData(t, 4.23 + 0 * t, 3.34 + 0.12 * np.sin(10.8 * t) + noise, 0 * t, np.full(t.size, np.nan),
...                   source="a.csv")
>>> check_usable(data)
>>> flat = RecordData(t, 4.23 + 0 * t, 3.34 + noise, 0 * t, np.full(t.size, np.nan), source="b.csv")
>>> try:
...     check_usable(flat)
... except UnusableRecordError as error:
...     print(str(error)[:60])
b.csv: T5_K shows no line of the cooler: the strongest line
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from cryod.analysis.record_data import RecordData
from cryod.cooler.line import coarse_line_frequency
from cryod.cooler.line_fit import fit_line
from cryod.records.record import RecordFormatError

#: At least this fraction of the rows must have both temperatures.
LEAST_VALID_FRACTION = 0.5
#: The line in T5 is measured in blocks this long (s): a cooler wandering by 1 % over 10 minutes moves
#: its phase by under 0.1 rad within one beyond what one frequency follows.
LINE_BLOCK_S = 30.0
#: At most this many blocks, spread over the record.
LINE_BLOCKS = 24
#: The cooler's line in T5 must be at least this many times T5's noise rms, and above this (K) in any case.
LEAST_LINE_OVER_NOISE = 10.0
SMALLEST_LINE_K = 1e-9


class UnusableRecordError(RecordFormatError):
    """A record the analysis cannot use, with what it is missing."""


def _row_text(index: int, time_s: np.ndarray) -> str:
    return f"data row {index + 1} (t = {time_s[index]:.3f} s)"


def check_usable(data: RecordData) -> None:
    """Refuse a record the analysis cannot use.

    Parameters
    ----------
    data : RecordData

    Raises
    ------
    UnusableRecordError
        Naming the record and what is missing (see the module doc).
    """
    source = data.source or "<record>"
    time_s = data.time_s
    steps = np.diff(time_s)
    if np.any(~np.isfinite(time_s)):
        index = int(np.flatnonzero(~np.isfinite(time_s))[0])
        raise UnusableRecordError(source, None, f"the time of data row {index + 1} is not a number: every row needs "
                                  "its instant")
    if np.any(steps <= 0.0):
        index = int(np.flatnonzero(steps <= 0.0)[0]) + 1
        raise UnusableRecordError(
            source, None, f"time does not increase at {_row_text(index, time_s)}, after {time_s[index - 1]:.3f} s: "
            "the analysis needs one run with increasing instants (two runs in one file, or a clock reset? split "
            "the record there)")
    valid = data.valid
    if np.mean(valid) < LEAST_VALID_FRACTION:
        missing = {name: int(np.count_nonzero(~np.isfinite(values)))
                   for name, values in (("T2_K", data.flange_K), ("T5_K", data.ptc_stage_K))}
        name = max(missing, key=lambda key: missing[key])
        values = data.flange_K if name == "T2_K" else data.ptc_stage_K
        first = int(np.flatnonzero(~np.isfinite(values))[0])
        raise UnusableRecordError(
            source, None, f"'{name}' is missing (empty or NaN) in {100.0 * missing[name] / time_s.size:.0f} % of the "
            f"rows, the first at {_row_text(first, time_s)}: at least {100 * LEAST_VALID_FRACTION:.0f} % of the "
            "rows need both T2_K and T5_K")
    _check_cooler_line(data, source)
    _check_heater_not_saturated(data, source)


def _check_cooler_line(data: RecordData, source: str) -> None:
    valid = data.valid
    elapsed, stage = data.elapsed_s[valid], data.ptc_stage_K[valid]
    try:
        coarse_line_frequency(elapsed, stage)
    except ValueError:
        raise UnusableRecordError(source, None, "T5_K is sampled too coarsely or too briefly to find the cooler's "
                                  "line in it") from None
    amplitude, noise, frequency = _line_and_noise(elapsed, stage)
    if not math.isfinite(noise) or (amplitude >= LEAST_LINE_OVER_NOISE * noise and amplitude > SMALLEST_LINE_K):
        return
    raise UnusableRecordError(
        source, None, f"T5_K shows no line of the cooler: the strongest line above 0.3 Hz is "
        f"{1e3 * amplitude:.3g} mK at {frequency:.3f} rad/s, {amplitude / max(noise, 1e-300):.3g} times T5's noise "
        f"({1e6 * noise:.3g} µK rms); the analysis replays the cooler's oscillation as T5 shows it and needs it at "
        f"least {LEAST_LINE_OVER_NOISE:g} times the noise (was the cooler running? is T5 the second-stage "
        "thermometer?)")


def _line_and_noise(elapsed: np.ndarray, stage: np.ndarray) -> tuple[float, float, float]:
    """The line's amplitude, what its fit leaves (rms) and its frequency: medians over blocks.

    Up to :data:`LINE_BLOCKS` blocks of :data:`LINE_BLOCK_S`, spread over the
    record, are each fitted at their own frequency (the spectrum's peak,
    refined by least squares), at the true sample instants: a cooler whose
    frequency wanders keeps its whole amplitude within a block, where one
    frequency over an hour smears it into the residual, and jittered instants
    stay where they were taken.
    """
    starts = np.arange(elapsed[0], elapsed[-1] - LINE_BLOCK_S, LINE_BLOCK_S)
    if starts.size > LINE_BLOCKS:
        starts = starts[np.linspace(0, starts.size - 1, LINE_BLOCKS).round().astype(int)]
    found = []
    for start in starts:
        inside = (elapsed >= start) & (elapsed < start + LINE_BLOCK_S)
        if np.count_nonzero(inside) < 64:
            continue
        time_s, values = elapsed[inside], stage[inside]
        try:
            coarse = coarse_line_frequency(time_s, values)
        except ValueError:
            continue
        half_bin = math.pi / LINE_BLOCK_S

        def left(frequency):
            return fit_line(time_s, values, frequency, orders=3, trend_order=2).residual_rms

        best = optimize.minimize_scalar(left, bounds=(coarse - half_bin, coarse + half_bin), method="bounded",
                                        options={"xatol": 1e-4})
        fit = fit_line(time_s, values, float(best.x), orders=3, trend_order=2)
        found.append((fit.amplitude[0], fit.residual_rms, float(best.x)))
    if not found:                   # shorter than a block: the whole record at one frequency
        frequency = coarse_line_frequency(elapsed, stage)
        fit = fit_line(elapsed, stage, frequency, orders=3, trend_order=3)
        return fit.amplitude[0], fit.residual_rms, frequency
    amplitude, noise, frequency = np.median(np.array(found), axis=0)
    return float(amplitude), float(noise), float(frequency)


def _check_heater_not_saturated(data: RecordData, source: str) -> None:
    heater = data.heater_w
    if np.ptp(heater) > 0.0:
        return
    power = float(heater[0])
    regulating = np.mean(np.isfinite(data.setpoint_K)) >= 0.5
    limit = data.heater_limit_w
    at_limit = limit is not None and power >= limit * (1.0 - 1e-6)
    if not (regulating or at_limit):
        return                      # an open-loop hold at one power: the line alone is analysed
    where = "at its limit" if at_limit or (regulating and power > 0.0) else "at 0 W"
    raise UnusableRecordError(
        source, None, f"the heater is saturated throughout: heater_W is {power:.6g} W ({where}) in every row"
        + (f" while the setpoint asks for regulation (setpoint_K {np.nanmedian(data.setpoint_K):.6g} K)"
           if regulating else "")
        + ": the heater paths are never seen, so no cause but the cooler's could be told; record a setpoint the "
        "heater can reach, heater steps or modulation")


__all__ = ["LEAST_LINE_OVER_NOISE", "LEAST_VALID_FRACTION", "UnusableRecordError", "check_usable"]
