"""Simulated time paced to a multiple of real time, slowing down when the machine cannot keep up.

A dry run faster than real time (``cryod simulate --speed 20``) runs on
:class:`PacedClock`: simulated time advances only when code waits on it
(``sleep_until``), as on :class:`~drivers.clock.VirtualClock`, and each
wait lasts the real time it stands for at the requested speed. The loop's
computation and the instruments' replies therefore take no simulated time, as
with ``--speed max``, and the simulated cryostat and instruments, which read
this clock, see the same physics whatever the machine's load.

When the machine falls behind (a busy machine, a slow tick), waits whose real
moment has passed return at once, so the run catches up; once it is more than
:data:`MAX_LAG_S` of real time behind, the lag is given up: the simulated
clock has run slower than asked for that stretch, and no deadline was missed
in simulated time. :meth:`PacedClock.achieved_speed` says how fast it really
ran.

Examples
--------
>>> clock = PacedClock(speed=1000.0)
>>> clock.sleep_until(0.08)                      # 80 µs of real time
>>> clock.now()
0.08
>>> clock.achieved_speed() > 0
True
"""

from __future__ import annotations

import collections
import threading
import time

from drivers.clock import VirtualClock

#: Real time (s) the clock may fall behind its pace and still catch up; beyond, the lag is given up.
MAX_LAG_S = 0.5
#: Real time (s) between the samples kept for the recent speed.
SAMPLE_INTERVAL_S = 0.25
#: Real time (s) the recent speed is measured over.
RECENT_S = 10.0


class PacedClock(VirtualClock):
    """Virtual time that advances at most ``speed`` times as fast as real time.

    Parameters
    ----------
    speed : float
        Requested simulated seconds per real second (> 0).
    max_lag_s : float
        Real time the clock may fall behind and still catch up (s).
    wall : callable
        Real monotonic time in s (injected for tests).
    sleep : callable
        Real sleep in s (injected for tests).
    """

    def __init__(self, speed: float, max_lag_s: float = MAX_LAG_S, wall=time.monotonic, sleep=time.sleep):
        if not speed > 0.0:
            raise ValueError(f"speed must be positive, got {speed}")
        super().__init__()
        self.speed = float(speed)
        self.max_lag_s = float(max_lag_s)
        self._wall = wall
        self._sleep = sleep
        start = wall()
        self._wall_start = start
        self._pace_wall = start              # the real instant simulated time _pace_sim is due at
        self._pace_sim = 0.0
        #: Real time given up because the machine was behind by more than ``max_lag_s`` (s).
        self.lag_given_up_s = 0.0
        self._samples: collections.deque[tuple[float, float]] = collections.deque(
            [(start, 0.0)], maxlen=int(RECENT_S / SAMPLE_INTERVAL_S) + 2)
        self._pace_lock = threading.Lock()

    def sleep_until(self, deadline_s: float) -> None:
        """Wait the real time up to ``deadline_s`` at the requested speed, then advance to it.

        Behind the pace, return at once (catching up); more than ``max_lag_s`` behind, the pace
        starts again from here.
        """
        with self._pace_lock:
            if deadline_s <= self._now:
                return
            due = self._pace_wall + (deadline_s - self._pace_sim) / self.speed
            wall = self._wall()
            if wall - due > self.max_lag_s:
                self.lag_given_up_s += wall - due
                self._pace_wall, self._pace_sim = wall, deadline_s
        if due > wall:
            self._sleep(due - wall)
        super().sleep_until(deadline_s)
        wall = self._wall()
        samples = self._samples
        if wall - samples[-1][0] >= SAMPLE_INTERVAL_S:
            samples.append((wall, self._now))

    def achieved_speed(self) -> float:
        """Simulated seconds per real second since the clock was made."""
        elapsed = self._wall() - self._wall_start
        return self._now / elapsed if elapsed > 0.0 else float("nan")

    def recent_speed(self) -> float:
        """Simulated seconds per real second over about the last :data:`RECENT_S` of real time."""
        wall = self._wall()
        samples = list(self._samples)
        old_wall, old_sim = next(((w, s) for w, s in samples if wall - w <= RECENT_S), samples[-1])
        elapsed = wall - old_wall
        return (self._now - old_sim) / elapsed if elapsed > 0.0 else float("nan")
