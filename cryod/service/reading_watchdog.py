"""The heater's setting may not outlive the readings it came from: a thread that switches it off when it does.

The supply holds the last power it was told until it is told another; the loop tells it a new one
every period, from fresh readings. When the loop does not run (stuck in a call, starved of the
processor, the interpreter held by something else), the supply goes on delivering a power computed
from readings that grow older. :class:`ReadingWatchdog` looks, from a thread of its own at the
loop's priority, at the age of the readings behind the heater's setting, on the daemon's clock: past
``safety.max_reading_age_s`` it switches the heater off through the
:class:`~cryod.service.heater_guard.HeaterGuard`, says so in the journal and the record, and the
loop's next setting is refused once (fault ``readings_too_old``), so that it goes through its
recovery (fresh valid readings) before it heats again. A late loop that still makes its settings
from fresh readings is left alone: late is not stale.

On a virtual or paced clock the daemon's time moves only when the loop waits, so the watchdog never
sees a stuck loop there; it guards the real clock.
"""

from __future__ import annotations

import logging
import math
import threading
from typing import Callable

from cryod.records.columns import Event
from cryod.service.faults import FaultCause
from cryod.service.heater_guard import HeaterGuard
from cryod.thread_priority import set_realtime_priority
from drivers.clock import Clock

log = logging.getLogger("cryod.watchdog")

#: The watchdog looks this many times per loop period.
LOOKS_PER_PERIOD = 4


class ReadingWatchdog:
    """Switches the heater off when its setting outlives its readings by more than ``max_age_s``.

    Parameters
    ----------
    loop : ControlLoop
        Read only: ``heater_w``, ``heater_reading_s``, ``config.safety.max_reading_age_s``.
    guard : HeaterGuard
        The loop's instruments.
    clock : Clock
        The daemon's clock.
    record : callable
        Takes the :class:`~cryod.records.columns.Event` that says it (the data log's ``put``).
    wait_s : float
        How long a heater call of the loop in progress is waited for (``instruments.timeout_s``).
    realtime_priority : int
        The loop's ``loop.realtime_priority`` (0: normal scheduling).
    sleep : callable
        Real-time pause between looks (injected for tests).
    """

    def __init__(self, loop, guard: HeaterGuard, clock: Clock, record: Callable[[Event], None], wait_s: float,
                 realtime_priority: int = 0, sleep: Callable[[float], None] | None = None):
        self.loop = loop
        self.guard = guard
        self.clock = clock
        self.record = record
        self.wait_s = wait_s
        self.realtime_priority = realtime_priority
        self._stopped = threading.Event()
        self._sleep = sleep or self._stopped.wait
        self._thread: threading.Thread | None = None
        #: Times it switched the heater off.
        self.switched_off = 0

    def _too_old(self) -> float | None:
        """The age of the readings behind the heater's setting when it is past the bound (s), else None."""
        loop = self.loop
        if not loop.heater_w > 0.0 or self.guard.switched_off is not None:    # off, or switched off already
            return None
        age_s = self.clock.now() - loop.heater_reading_s
        return age_s if math.isfinite(age_s) and age_s > loop.config.safety.max_reading_age_s else None

    def look(self) -> None:
        """One look: switch the heater off when its setting has outlived its readings."""
        age_s = self._too_old()
        if age_s is None:
            return
        bound_s = self.loop.config.safety.max_reading_age_s
        reason = (f"{FaultCause.READINGS_TOO_OLD}: the heater's setting came from readings {age_s:.3f} s old and the "
                  f"loop made no newer one (safety.max_reading_age_s {bound_s:g})")
        switched, problem = self.guard.switch_off_if(lambda: self._too_old() is not None, reason, self.wait_s)
        if problem is not None:
            log.critical("%s; switching the heater off from the watchdog failed: %s", reason, problem)
            self.record(Event("watchdog", f"{reason}; switching the heater off failed: {problem}"))
        elif switched:
            self.switched_off += 1
            log.critical("%s: heater switched off from the watchdog's thread", reason)
            self.record(Event("watchdog", f"{reason}: heater switched off from the watchdog's thread; the loop "
                                          f"recovers from fresh readings"))

    def _run(self) -> None:
        problem = set_realtime_priority(self.realtime_priority) if self.realtime_priority > 0 else None
        if problem:
            log.warning("reading watchdog: %s", problem)
        period_s = self.loop.period_s / LOOKS_PER_PERIOD
        while not self._stopped.is_set():
            self._sleep(period_s)
            try:
                self.look()
            except Exception:           # the watchdog must go on looking whatever one look met
                log.exception("reading watchdog: a look failed")

    def start(self) -> None:
        """Look from a thread of its own."""
        self._thread = threading.Thread(target=self._run, name="cryod-watchdog", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stopped.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None


__all__ = ["ReadingWatchdog", "LOOKS_PER_PERIOD"]
