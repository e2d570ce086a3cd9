"""How long the daemon waits on an instrument, and why that keeps the heater and the watchdog safe.

Two waits, each for one reply:

* **on the loop's path** (readings, heater settings, the heater-off): at most
  :attr:`InstrumentWaits.loop_reply_s`, five loop periods (or ``instruments.timeout_s`` if
  that is shorter). A reply later than that is no reply for the loop: the heater goes off,
  the loop recovers. An instrument that stops answering therefore holds the heater on for a
  bounded time, whatever ``instruments.timeout_s`` says, while a slow adapter or a loaded
  machine that delays a reply by a few periods does not stop the regulation;
* **opening, configuring, reconnecting** (``*IDN?``, the error queue after a configuration):
  ``instruments.timeout_s``, since an instrument may take longer to take in a
  configuration than to give a reading.

From these follow the two figures that matter:

* :attr:`InstrumentWaits.heater_off_s`: the longest the heater-off can take. The off is one
  message confirmed by its reply (``drivers.heater``); on a dropped link the connection is
  opened again once first, and a reply owed from before is dropped first;
* :meth:`InstrumentWaits.fault_to_off_s`: from a fault to the supply told 0 A. The tick that
  finds the fault starts within one loop period; its reading fails within the reading's own
  time and one loop-path reply; then the heater-off.

The loop's thread never goes longer without finishing a tick than
:attr:`InstrumentWaits.longest_tick_s` (a reconnect waits at most :data:`RECONNECT_WAITS`
replies of ``instruments.timeout_s``: one new connection, one reply; the first that fails
ends the attempt). The watchdog is pinged at the end of a tick, at most every
:data:`WATCHDOG_PING_SHARE` of its interval, so it is fed within that spacing plus the
longest tick; :meth:`InstrumentWaits.watchdog_problem` refuses a configuration for which that
takes more than :data:`WATCHDOG_USABLE_SHARE` of the shipped unit's ``WatchdogSec``, the rest
being room for a machine under load. A stop (SIGTERM) and a ``heater-off`` from the control
socket are carried out at the next tick boundary, so within the longest tick too (a command is
answered when that tick ends).

Examples
--------
>>> waits = InstrumentWaits(loop_period_s=0.08, timeout_s=1.0)
>>> waits.loop_reply_s, round(waits.heater_off_s, 3)
(0.4, 0.85)
>>> round(waits.fault_to_off_s(reading_delay_s=0.042), 3)
1.372
>>> waits.watchdog_problem() is None
True
>>> print(InstrumentWaits(loop_period_s=0.08, timeout_s=30.0).watchdog_problem())
30 s per reply: a reconnect on the loop's thread may wait 2 of them, so a tick may last 61 s and the watchdog (10 s, WatchdogSec in systemd/cryod.service) go unfed for 63.5 s, more than the 7.5 s the daemon's own waits may take of it; at most 1.985 s per reply fits
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.transports.visa import LATE_REPLY_WINDOW_S

#: ``WatchdogSec`` of the shipped units (systemd/cryod.service, cryod@.service): the configuration is held to it.
UNIT_WATCHDOG_S = 10.0
#: The loop pings the watchdog at the end of a tick, at most once per this share of its interval.
WATCHDOG_PING_SHARE = 0.25
#: The longest the watchdog may go unfed by the configuration's own waits, as a share of its interval.
WATCHDOG_USABLE_SHARE = 0.75
#: A reply on the loop's path is given this many loop periods.
LOOP_REPLY_PERIODS = 5.0
#: Waits of ``instruments.timeout_s`` one reconnect attempt can make: a connection, then a reply.
RECONNECT_WAITS = 2


@dataclass(frozen=True)
class InstrumentWaits:
    """The waits on instruments of a configuration (s).

    Parameters
    ----------
    loop_period_s : float
        ``loop.period_s``.
    timeout_s : float
        ``instruments.timeout_s``: the longest wait for a reply while opening, configuring or
        reconnecting.
    """

    loop_period_s: float
    timeout_s: float

    @property
    def loop_reply_s(self) -> float:
        """Longest wait for one reply on the loop's path (s): five loop periods, or ``timeout_s`` if shorter."""
        return min(self.timeout_s, LOOP_REPLY_PERIODS * self.loop_period_s)

    @property
    def heater_off_s(self) -> float:
        """Longest the heater-off can take (s): a new connection after a dropped one and the off's own
        message with its confirmation (one loop-path reply each), after dropping a late reply."""
        return 2.0 * self.loop_reply_s + LATE_REPLY_WINDOW_S

    def fault_to_off_s(self, reading_delay_s: float) -> float:
        """Longest time from an instrument fault to the heater-off done (s).

        Parameters
        ----------
        reading_delay_s : float
            Longest time from a trigger to both readings (the DMMs' timing).
        """
        return self.loop_period_s + reading_delay_s + self.loop_reply_s + self.heater_off_s

    @property
    def longest_tick_s(self) -> float:
        """Longest time between the ends of two ticks (s): one period, a reconnect's waits (each with a
        late reply dropped first), then a heater-off."""
        return (self.loop_period_s + RECONNECT_WAITS * (self.timeout_s + LATE_REPLY_WINDOW_S)
                + self.heater_off_s)

    def largest_timeout_s(self, watchdog_s: float = UNIT_WATCHDOG_S) -> float:
        """The largest ``timeout_s`` this loop period fits with the watchdog (s; 0 or less: none)."""
        # longest_tick_s = period + RECONNECT_WAITS (timeout + window) + 2 loop_reply + window, solved for timeout
        budget = ((WATCHDOG_USABLE_SHARE - WATCHDOG_PING_SHARE) * watchdog_s - self.loop_period_s
                  - (RECONNECT_WAITS + 1) * LATE_REPLY_WINDOW_S)
        loop_reply_cap_s = LOOP_REPLY_PERIODS * self.loop_period_s
        timeout_s = (budget - 2.0 * loop_reply_cap_s) / RECONNECT_WAITS
        if timeout_s >= loop_reply_cap_s:
            return timeout_s
        return budget / (RECONNECT_WAITS + 2.0)          # a timeout below the cap is the loop's reply wait too

    def watchdog_problem(self, watchdog_s: float = UNIT_WATCHDOG_S,
                         where: str = "WatchdogSec in systemd/cryod.service") -> str | None:
        """Why these waits can leave the watchdog unfed too long, or None when they fit.

        Parameters
        ----------
        watchdog_s : float
            The watchdog's interval (s); the shipped units' by default.
        where : str
            Where that interval is set, for the message.
        """
        ping_s = WATCHDOG_PING_SHARE * watchdog_s
        limit_s = WATCHDOG_USABLE_SHARE * watchdog_s
        if ping_s + self.longest_tick_s <= limit_s:
            return None
        largest = self.largest_timeout_s(watchdog_s)
        fits = (f"at most {largest:.4g} s per reply fits" if largest >= 0.01
                else f"no timeout fits a {self.loop_period_s:g} s loop period")
        return (f"{self.timeout_s:g} s per reply: a reconnect on the loop's thread may wait {RECONNECT_WAITS} of "
                f"them, so a tick may last {self.longest_tick_s:.3g} s and the watchdog ({watchdog_s:g} s, {where}) "
                f"go unfed for {ping_s + self.longest_tick_s:.3g} s, more than the {limit_s:g} s the daemon's own "
                f"waits may take of it; {fits}")


__all__ = ["InstrumentWaits", "UNIT_WATCHDOG_S", "WATCHDOG_PING_SHARE", "LOOP_REPLY_PERIODS"]
