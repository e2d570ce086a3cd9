"""The heater between two threads: the loop's settings, and an off from outside that holds.

The loop thread sets the heater every cycle. When the process is told to end (a signal, an
exception in another thread) and the loop does not stop by itself in time (it is stuck in an
instrument call, or in a bug), the heater is switched off from another thread
(:meth:`HeaterGuard.hold_off`); when the loop has not made a setting from fresh readings for
``safety.max_reading_age_s``, the reading watchdog switches it off (:meth:`HeaterGuard.switch_off_if`)
and the loop's next setting is refused once, so that it recovers from fresh readings.
:class:`HeaterGuard` wraps the loop's instruments so that the two never talk to the supply at
once, and so that once held off, no later setting of the loop turns the heater back on: it fails
with :class:`HeaterHeldOff` instead, and the loop stops.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

from drivers.errors import InstrumentError
from drivers.thermometer_pair import PairReading

if TYPE_CHECKING:
    from cryod.service.loop import Instruments


class HeaterHeldOff(InstrumentError):
    """The heater was switched off from outside the loop; no setting turns it back on."""


class HeaterSwitchedOff(InstrumentError):
    """The heater was switched off from outside the loop because its setting had outlived the readings it came
    from (:class:`cryod.service.reading_watchdog.ReadingWatchdog`); the loop's next setting is refused once, so
    that the loop goes through a fault and fresh readings before it heats again."""


class HeaterGuard:
    """The loop's :class:`~cryod.service.loop.Instruments` with every heater call serialised.

    Parameters
    ----------
    instruments : Instruments
        What the loop would use directly.
    """

    def __init__(self, instruments: Instruments) -> None:
        self.instruments = instruments
        self._heater = threading.Lock()
        #: Why the heater is held off (None while the loop may set it).
        self.held_off: str | None = None
        #: Why the heater was switched off from outside since the loop last switched it off itself (None: it
        #: was not); the loop's next setting is refused with it.
        self.switched_off: str | None = None

    def measure(self) -> PairReading:
        return self.instruments.measure()

    def set_heater_power(self, power_w: float) -> None:
        with self._heater:
            if self.held_off is not None:
                raise HeaterHeldOff("heater supply", f"{power_w:.4g} W not applied: held off ({self.held_off})")
            if self.switched_off is not None:
                reason, self.switched_off = self.switched_off, None
                raise HeaterSwitchedOff("heater supply", f"{power_w:.4g} W not applied: {reason}")
            self.instruments.set_heater_power(power_w)

    def heater_off(self) -> float:
        with self._heater:
            confirmed_s = self.instruments.heater_off()
            self.switched_off = None            # the loop knows the heater is off: nothing more to tell it
            return confirmed_s

    def examine(self, error: InstrumentError) -> None:
        """A failing DMM's error queue (the supply's is read by its driver, after its own off)."""
        self.instruments.examine(error)

    def reconnect(self) -> None:
        with self._heater:          # reconfigures the supply (output off): not while another thread uses it
            self.instruments.reconnect()

    def close(self) -> None:
        with self._heater:
            self.instruments.close()

    def switch_off_if(self, still_needed, reason: str, wait_s: float) -> tuple[bool, str | None]:
        """Heater off from this thread when ``still_needed()`` holds once the loop's heater call in progress (if
        any) has ended; the loop's next setting is then refused (:class:`HeaterSwitchedOff`) so that it goes
        through a fault. Waits up to ``wait_s`` for a heater call of the loop in progress.

        Returns
        -------
        (bool, str or None)
            Whether it switched the heater off, and why it could not when it had to.
        """
        if not self._heater.acquire(timeout=wait_s):
            return False, (f"the loop's heater call did not end within {wait_s:g} s: the supply may still deliver "
                           f"the last setting; check it at the supply")
        try:
            if not still_needed():
                return False, None
            self.instruments.heater_off()
            self.switched_off = reason
        except InstrumentError as error:
            return False, f"could not switch the heater off ({error}); check it at the supply"
        finally:
            self._heater.release()
        return True, None

    def hold_off(self, reason: str, wait_s: float) -> str | None:
        """Heater off from this thread and held off; None when done, else why not.

        Waits up to ``wait_s`` for a heater call of the loop in progress; a supply that does not
        answer within that is reported, not waited for."""
        if not self._heater.acquire(timeout=wait_s):
            return (f"the loop's heater call did not end within {wait_s:g} s: the supply may still deliver "
                    f"the last setting; check it at the supply")
        try:
            self.held_off = reason
            self.instruments.heater_off()
        except InstrumentError as error:
            return f"could not switch the heater off ({error}); check it at the supply"
        finally:
            self._heater.release()
        return None
