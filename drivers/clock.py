"""What the drivers need of time: the present instant and a wait until a deadline.

Drivers take a clock instead of calling :mod:`time` so that the same code runs
in service (the real monotonic clock below) and on a virtual clock in
simulation, where waiting costs nothing. Any object with these two methods
will do.

Examples
--------
>>> clock = MonotonicClock()
>>> start = clock.now()
>>> clock.sleep_until(start)          # a deadline already reached returns at once
>>> clock.now() >= start
True
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """Time in seconds on a monotonic scale."""

    def now(self) -> float:
        """Current time in s; never goes backwards."""

    def sleep_until(self, deadline_s: float) -> None:
        """Return at (or just after) ``deadline_s``; at once if it has passed."""


class MonotonicClock:
    """The real monotonic clock (``time.monotonic``)."""

    is_virtual = False

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, deadline_s: float) -> None:
        remaining = deadline_s - time.monotonic()
        if remaining > 0.0:
            time.sleep(remaining)
