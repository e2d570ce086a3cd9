"""Each alarm's figure, from the loop's rows, and its condition against the alarm's settings.

The windowed figures (T2's mean and standard deviation, the heater's mean) come from
:class:`RecentValues`, a ring of the latest readings taken while the loop regulates at
one steady setpoint: a new setpoint, a ramp or anything but regulation starts it afresh,
so no window mixes two setpoints. The cooler's line on T5 is followed by the same
phase tracker the feedforward locks to (:class:`cryod.cooler.phase.CoolerPhaseTracker`).

Examples
--------
>>> recent = RecentValues(capacity=100)
>>> for tick in range(50):
...     recent.append(0.08 * tick, 5.0 + 1e-4 * (tick % 2))
>>> times, values = recent.window(2.0, now_s=0.08 * 49)
>>> len(values), round(float(values.mean() - 5.0) * 1e6, 1)
(25, 52.0)
>>> deviation_condition(DeviationAlarm(threshold_K=5e-5, deadband_K=1e-5), values.mean(), 5.0, 2.0).holds
True
"""

from __future__ import annotations

import math

import numpy as np

from cryod.alarms.latch import Condition
from cryod.alarms.settings import (
    CoolerLineLostAlarm,
    DeviationAlarm,
    HeaterNearTopAlarm,
    PtcStageWarmAlarm,
    StabilityAlarm,
)
from cryod.cooler.phase import CoolerPhase

#: The heater power is averaged over this long for its alarm (s): about 17 cooler periods, so the
#: feedforward's waveform averages out.
HEATER_AVERAGE_S = 10.0


class RecentValues:
    """The latest (time, value) pairs, oldest first, as numpy views without copying.

    Every pair is written twice, at ``i`` and ``i + capacity``, so the latest ``capacity`` pairs
    are always one contiguous slice.

    Parameters
    ----------
    capacity : int
        Pairs kept at most.
    """

    def __init__(self, capacity: int):
        self.capacity = int(capacity)
        self._times = np.full(2 * self.capacity, np.nan)
        self._values = np.full(2 * self.capacity, np.nan)
        self._next = 0
        self._filled = 0

    def __len__(self) -> int:
        return self._filled

    def reset(self) -> None:
        """Forget every pair."""
        self._filled = 0

    def append(self, time_s: float, value: float) -> None:
        index, capacity = self._next, self.capacity
        self._times[index] = self._times[index + capacity] = time_s
        self._values[index] = self._values[index + capacity] = value
        self._next = (index + 1) % capacity
        self._filled = min(self._filled + 1, capacity)

    @property
    def first_time_s(self) -> float:
        """The oldest pair's time (NaN when empty)."""
        if not self._filled:
            return math.nan
        return float(self._times[self._next + self.capacity - self._filled])

    def window(self, span_s: float, now_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The pairs of the last ``span_s`` up to ``now_s`` (times after ``now_s - span_s``): times and values."""
        end = self._next + self.capacity
        times = self._times[end - self._filled:end]
        start = int(np.searchsorted(times, now_s - span_s, side="right"))
        return times[start:], self._values[end - self._filled + start:end]


def covers(recent: RecentValues, span_s: float, now_s: float, period_s: float) -> bool:
    """Whether ``recent`` holds readings from the whole of the last ``span_s`` (one period of slack)."""
    return now_s - recent.first_time_s >= span_s - 1.5 * period_s


def _microkelvin(value_K: float) -> str:
    return f"{value_K * 1e6:.1f} µK" if abs(value_K) < 1e-3 else f"{value_K * 1e3:.3f} mK"


def _against(value: float, threshold: float, deadband: float) -> bool | None:
    """Above the threshold: True; at or below threshold - deadband: False; between: None."""
    if value > threshold:
        return True
    return False if value <= threshold - deadband else None


def deviation_condition(settings: DeviationAlarm, mean_K: float, setpoint_K: float, window_s: float) -> Condition:
    """T2's mean over the window against the setpoint."""
    offset = float(mean_K) - setpoint_K
    return Condition(_against(abs(offset), settings.threshold_K, settings.deadband_K), offset,
                     f"T2 averaged over {window_s:g} s {'+' if offset >= 0 else '-'}{_microkelvin(abs(offset))} "
                     f"from the setpoint {setpoint_K:.4f} K (threshold {_microkelvin(settings.threshold_K)})")


def stability_condition(settings: StabilityAlarm, deviation_K: float) -> Condition:
    """T2's standard deviation over the window against the threshold."""
    return Condition(_against(deviation_K, settings.threshold_K, settings.deadband_K), float(deviation_K),
                     f"T2's standard deviation over {settings.window_s:g} s {_microkelvin(deviation_K)} "
                     f"(threshold {_microkelvin(settings.threshold_K)})")


def ptc_stage_condition(settings: PtcStageWarmAlarm, ptc_stage_K: float) -> Condition:
    """T5 against the threshold; no reading changes nothing."""
    if not math.isfinite(ptc_stage_K):
        return Condition(None, math.nan, "no T5 reading")
    return Condition(_against(ptc_stage_K, settings.threshold_K, settings.deadband_K), ptc_stage_K,
                     lambda: f"T5 {ptc_stage_K:.4f} K (threshold {settings.threshold_K:g} K)")


def heater_condition(settings: HeaterNearTopAlarm, mean_w: float, max_power_w: float) -> Condition:
    """The heater's mean power against its fraction of the top."""
    fraction = float(mean_w) / max_power_w
    held = True if fraction >= settings.fraction else _against(fraction, settings.fraction, settings.deadband)
    return Condition(held, fraction,
                     f"heater averaged over {HEATER_AVERAGE_S:g} s {mean_w * 1e3:.1f} mW, {fraction * 100:.1f} % of "
                     f"its top R I_max^2 = {max_power_w * 1e3:.1f} mW (threshold {settings.fraction * 100:g} %)")


def cooler_line_condition(settings: CoolerLineLostAlarm, phase: CoolerPhase | None) -> Condition:
    """The tracker's lock on T5's cooler line: lost while it is not locked."""
    if phase is None:
        return Condition(None, math.nan, "no T5 reading yet")
    amplitude = phase.amplitude_K
    if phase.locked:
        return Condition(False, amplitude, lambda: f"cooler line on T5 {amplitude * 1e3:.1f} mK, locked at "
                                                   f"{phase.frequency_rad_s / (2 * math.pi):.4f} Hz")

    def lost() -> str:
        why = (f"amplitude {amplitude * 1e3:.1f} mK, below {settings.min_amplitude_K * 1e3:g} mK"
               if amplitude < settings.min_amplitude_K else f"amplitude {amplitude * 1e3:.1f} mK but no steady phase")
        return f"cooler line on T5 lost: {why} (the cooler stopped, or T5 no longer sees it)"
    return Condition(True, amplitude, lost)
