"""Injected time: the monotonic clock in service, a scaled or virtual one in simulation.

Everything that needs "now" or has to wait takes a clock, so an hour of
cryostat runs in seconds on :class:`VirtualClock` and tests never sleep.

Examples
--------
>>> clock = VirtualClock()
>>> clock.sleep_until(0.08)
>>> clock.now()
0.08
"""

from __future__ import annotations

import threading
import time

from drivers.clock import Clock, MonotonicClock

__all__ = ["Clock", "MonotonicClock", "ScaledClock", "VirtualClock"]


class ScaledClock:
    """Real time running ``speed`` times faster (``cryod --simulate --speed X``).

    Parameters
    ----------
    speed : float
        Simulated seconds per real second (> 0).
    """

    is_virtual = False

    def __init__(self, speed: float):
        if not speed > 0.0:
            raise ValueError(f"speed must be positive, got {speed}")
        self.speed = float(speed)
        self._real_start = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._real_start) * self.speed

    def sleep_until(self, deadline_s: float) -> None:
        remaining = (deadline_s - self.now()) / self.speed
        if remaining > 0.0:
            time.sleep(remaining)


class VirtualClock:
    """Simulated time that advances only when asked to (thread-safe).

    Parameters
    ----------
    start_s : float
        Initial time in s.
    """

    is_virtual = True

    def __init__(self, start_s: float = 0.0):
        self._now = float(start_s)
        self._lock = threading.Lock()

    def now(self) -> float:
        return self._now

    def sleep_until(self, deadline_s: float) -> None:
        with self._lock:
            if deadline_s > self._now:
                self._now = float(deadline_s)

    def advance(self, duration_s: float) -> None:
        """Move time forward by ``duration_s`` (s, not negative)."""
        if duration_s < 0.0:
            raise ValueError(f"cannot advance by a negative duration {duration_s}")
        with self._lock:
            self._now += float(duration_s)
