"""Injected time: the present instant and a wait until a deadline, real, scaled or virtual.

Drivers and the daemon take a clock instead of calling :mod:`time` so that the
same code runs in service (the real monotonic clock) and on a virtual clock in
simulation, where waiting costs nothing: an hour of cryostat runs in seconds
and tests never sleep. Any object with the two methods of :class:`Clock` will
do; the clocks are here, below everything that uses them.

Examples
--------
>>> clock = MonotonicClock()
>>> start = clock.now()
>>> clock.sleep_until(start)          # a deadline already reached returns at once
>>> clock.now() >= start
True
>>> clock = VirtualClock()
>>> clock.sleep_until(0.08)
>>> clock.now()
0.08
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Clock(Protocol):
    """Time in seconds on a monotonic scale."""

    #: The Unix time (s) a daemon started on this clock dates its record from; None: the wall time at which
    #: it starts. A run on virtual time can be dated to any day (the tests date theirs away from UTC
    #: midnight, where a record is split into two days' files).
    wall_start_s: float | None

    def now(self) -> float:
        """Current time in s; never goes backwards."""

    def sleep_until(self, deadline_s: float) -> None:
        """Return at (or just after) ``deadline_s``; at once if it has passed."""


class MonotonicClock:
    """The real monotonic clock (``time.monotonic``)."""

    is_virtual = False
    wall_start_s: float | None = None

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, deadline_s: float) -> None:
        remaining = deadline_s - time.monotonic()
        if remaining > 0.0:
            time.sleep(remaining)


class ScaledClock:
    """Real time running ``speed`` times faster (``cryod --simulate --speed X``).

    Parameters
    ----------
    speed : float
        Simulated seconds per real second (> 0).
    """

    is_virtual = False
    wall_start_s: float | None = None

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
    wall_start_s: float | None = None

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


def clock_for_speed(speed: float | str) -> Clock:
    """The clock of a simulated run at ``speed`` (``cryod --simulate --speed``): virtual for ``"max"``,
    the real one at 1, paced above 1 (:class:`drivers.paced_clock.PacedClock`: simulated time that
    slows when the machine cannot keep the pace), real time scaled below 1."""
    if speed == "max":
        return VirtualClock()
    if isinstance(speed, str):
        raise ValueError(f"speed must be a number or 'max', got {speed!r}")
    if speed > 1.0:
        from drivers.paced_clock import PacedClock  # it builds on VirtualClock, defined above

        return PacedClock(speed)
    return MonotonicClock() if speed == 1.0 else ScaledClock(speed)
