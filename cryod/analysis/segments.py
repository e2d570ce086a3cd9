"""Cutting a record into what was done: PI segments, heater holds, modulation, and the steps between holds.

* ``closed loop``: the setpoint column is set (one segment per setpoint, a
  jump of more than 10 mK starts a new one; a ramp stays one segment).
* ``hold``: open loop with the heater constant for at least 5 s.
* ``modulated``: open loop, the heater changing, for at least 5 s; split where
  its dominant frequency changes (30 s windows).
* a step: one hold followed directly by another at a different power.

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 100.0, 0.1)
>>> heater = np.where(t < 40.0, 0.0, 0.01)
>>> [s.kind for s in find_segments(t, heater, np.full(t.size, np.nan))]
['hold', 'hold']
>>> [round(s.time_s, 1) for s in find_steps(t, heater, find_segments(t, heater, np.full(t.size, np.nan)))]
[40.0]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Shortest hold or modulated stretch kept as a segment (s).
SHORTEST_SEGMENT_S = 5.0
#: A setpoint jump larger than this starts a new closed-loop segment (K).
SETPOINT_JUMP_K = 0.01
#: Modulated stretches are split where the heater's dominant frequency changes by 15 % between windows of this (s).
MODULATION_WINDOW_S = 30.0


@dataclass(frozen=True)
class RecordSegment:
    """Samples ``start_index`` to ``stop_index - 1`` of a record, of one kind."""

    kind: str
    start_index: int
    stop_index: int
    start_s: float
    stop_s: float
    mean_heater_w: float
    setpoint_K: float

    @property
    def duration_s(self) -> float:
        return self.stop_s - self.start_s

    def label(self) -> str:
        what = {"closed loop": f"PI to {self.setpoint_K:.3f} K", "hold": f"hold {1e3 * self.mean_heater_w:.2f} mW",
                "modulated": f"modulated, mean {1e3 * self.mean_heater_w:.2f} mW"}[self.kind]
        return f"{what}, {self.start_s:.0f}-{self.stop_s:.0f} s"


@dataclass(frozen=True)
class HeaterStep:
    """An open-loop change of heater power from one hold to the next."""

    index: int
    time_s: float
    before_w: float
    after_w: float
    before: RecordSegment
    after: RecordSegment


def _runs(labels: np.ndarray):
    """(start, stop) of the runs of equal labels."""
    edges = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    starts = np.concatenate(([0], edges))
    stops = np.concatenate((edges, [labels.size]))
    return list(zip(starts.tolist(), stops.tolist()))


def find_segments(time_s, heater_w, setpoint_K) -> list[RecordSegment]:
    """Segments of a record, in time order (see the module's description)."""
    time_s = np.asarray(time_s, dtype=float)
    heater_w = np.asarray(heater_w, dtype=float)
    setpoint_K = np.asarray(setpoint_K, dtype=float)
    closed = np.isfinite(setpoint_K)
    labels = np.zeros(time_s.size, dtype=int)            # 0 open, >0 closed-loop segment number
    number = 0
    for start, stop in _runs(closed.astype(int)):
        if not closed[start]:
            continue
        number += 1
        jumps = np.flatnonzero(np.abs(np.diff(setpoint_K[start:stop])) > SETPOINT_JUMP_K) + 1
        bounds = [start] + (start + jumps).tolist() + [stop]
        for first, last in zip(bounds[:-1], bounds[1:]):
            labels[first:last] = number
            number += 1
    segments = []
    end_time = time_s[-1] + (time_s[-1] - time_s[-2] if time_s.size > 1 else 0.0)

    def make(kind, start, stop):
        stop_time = time_s[stop] if stop < time_s.size else end_time
        segments.append(RecordSegment(kind, start, stop, float(time_s[start]), float(stop_time),
                                      float(np.mean(heater_w[start:stop])),
                                      float(np.nanmean(setpoint_K[start:stop])) if kind == "closed loop" else np.nan))

    for start, stop in _runs(labels):
        if labels[start] > 0:
            make("closed loop", start, stop)
            continue
        _open_segments(time_s, heater_w, start, stop, make)
    return segments


def _open_segments(time_s, heater_w, start, stop, make) -> None:
    """Holds and modulated stretches of an open-loop run."""
    power = heater_w[start:stop]
    changed = np.concatenate(([True], np.abs(np.diff(power)) > 1e-12 + 1e-9 * np.abs(power[1:])))
    hold_id = np.cumsum(changed)            # same id while the power stays put
    pieces = []
    for first, last in _runs(hold_id):
        first, last = first + start, last + start
        stop_time = time_s[last] if last < time_s.size else time_s[-1]
        pieces.append(("hold" if stop_time - time_s[first] >= SHORTEST_SEGMENT_S else "varying", first, last))
    merged: list[tuple[str, int, int]] = []
    for kind, first, last in pieces:
        if merged and merged[-1][0] == kind == "varying":
            merged[-1] = ("varying", merged[-1][1], last)
        else:
            merged.append((kind, first, last))
    for kind, first, last in merged:
        stop_time = time_s[last] if last < time_s.size else time_s[-1]
        if kind == "hold":
            make("hold", first, last)
        elif stop_time - time_s[first] >= SHORTEST_SEGMENT_S:
            for piece_first, piece_last in _split_by_frequency(time_s, heater_w, first, last):
                make("modulated", piece_first, piece_last)


def _split_by_frequency(time_s, heater_w, first, last):
    """Pieces of a modulated stretch with one dominant heater frequency each (windows of 30 s)."""
    edges = np.searchsorted(time_s, np.arange(time_s[first], time_s[last - 1], MODULATION_WINDOW_S))
    edges = np.unique(np.concatenate((edges[(edges > first) & (edges < last)], [first, last])))
    frequencies = []
    for start, stop in zip(edges[:-1], edges[1:]):
        power = heater_w[start:stop] - np.mean(heater_w[start:stop])
        if power.size < 8:
            frequencies.append(np.nan)
            continue
        spectrum = np.abs(np.fft.rfft(power * np.hanning(power.size)))
        spectrum[0] = 0.0
        frequencies.append(float(np.argmax(spectrum)) / max(time_s[stop - 1] - time_s[start], 1e-9))
    pieces, start = [], first
    for index in range(1, len(frequencies)):
        before, now = frequencies[index - 1], frequencies[index]
        if np.isfinite(before) and np.isfinite(now) and abs(now - before) > 0.15 * max(before, now):
            pieces.append((start, int(edges[index])))
            start = int(edges[index])
    pieces.append((start, last))
    return pieces


def find_steps(time_s, heater_w, segments: list[RecordSegment]) -> list[HeaterStep]:
    """Steps: a hold followed directly (within one sample) by a hold at another power."""
    steps = []
    for before, after in zip(segments[:-1], segments[1:]):
        if before.kind == after.kind == "hold" and after.start_index - before.stop_index <= 1:
            if abs(after.mean_heater_w - before.mean_heater_w) > 0.0:
                steps.append(HeaterStep(after.start_index, float(time_s[after.start_index]),
                                        before.mean_heater_w, after.mean_heater_w, before, after))
    return steps
