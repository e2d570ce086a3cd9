"""The loop's fault episodes: when the heater may be used again after a fault, and when to give up.

An episode runs from a first recoverable fault until the loop has run clean for
``safety.recovery_timeout_s`` after its last resume. The recovery timeout counts
from the episode's start, and every resume within it doubles the valid readings
the next resume needs: a fault that keeps coming back is not retried at full
rate, and is not given a new timeout each time. At start-up, and after a
heater-off or a fault, the loop holds the heater off until enough valid,
in-range readings came in a row.

The loop tells :class:`FaultEpisodes` what happened (a fault, a reading, a
resume, a reconnect, a clean tick) and asks it what to do (resume now? give
up? reconnect?); the episode's state lives here and nowhere else.

Examples
--------
>>> from cryod.config import SafetyConfig
>>> safety = SafetyConfig(flange_max_K=10.0, ptc_stage_max_K=10.0, max_repeated_readings=50,
...                       valid_readings_to_resume=5, recovery_timeout_s=60.0)
>>> episodes = FaultEpisodes(safety, period_s=0.08)
>>> episodes.recovering_from_fault(now_s=10.0)        # seconds left of the recovery timeout
60.0
>>> [episodes.count_reading(True) for _ in range(5)][-1] >= episodes.readings_to_resume()
True
>>> episodes.resumed(at_s=10.4).startswith(" (resume 1 since the first fault 0.4 s ago")
True
>>> episodes.readings_to_resume()                     # doubled for the next resume in this episode
10
"""

from __future__ import annotations

import math

from cryod.config import SafetyConfig

#: Reconnect attempts are at least this far apart (s of the loop's clock).
RECONNECT_INTERVAL_S = 1.0


class FaultEpisodes:
    """The state of the loop's recovery: the episode under way, its resumes, the valid readings so far.

    Parameters
    ----------
    safety : SafetyConfig
        ``valid_readings_to_resume`` and ``recovery_timeout_s`` (a reload hands over new ones with
        :meth:`configure`).
    period_s : float
        The loop's period (s): a recovery timeout's worth of readings bounds the doubling.
    """

    def __init__(self, safety: SafetyConfig, period_s: float):
        self.safety = safety
        self.period_s = period_s
        self.start_s: float | None = None         #: when the episode's first fault came (clock), None: no episode
        self.resumes = 0                          #: resumes since the episode began
        self._resumed_at_s = -math.inf
        self._last_reconnect_s = -math.inf
        self._valid_in_a_row = 0
        self._hold_reported = False

    def configure(self, safety: SafetyConfig) -> None:
        """Use a reloaded ``safety`` section from now on."""
        self.safety = safety

    # -- told what happened --------------------------------------------------------
    def reading_lost(self) -> None:
        """A fault: the valid readings in a row start again from none."""
        self._valid_in_a_row = 0

    def recovering_from_fault(self, now_s: float) -> float:
        """The loop starts recovering from a recoverable fault at ``now_s``: an episode begins unless one is
        under way, and a reconnect may be tried at once. Returns the seconds left of the recovery timeout."""
        if self.start_s is None:
            self.start_s = now_s
        self._last_reconnect_s = -math.inf
        return self.safety.recovery_timeout_s - (now_s - self.start_s)

    def count_reading(self, valid: bool) -> int:
        """A reading while the heater is held off: valid and in range, or not. Returns the valid ones in a row."""
        self._valid_in_a_row = self._valid_in_a_row + 1 if valid else 0
        return self._valid_in_a_row

    def resumed(self, at_s: float) -> str:
        """The loop used the heater again after its hold, at ``at_s``: the note for the ``resumed`` event
        (empty outside an episode)."""
        self._hold_reported = False
        if self.start_s is None:
            return ""
        self.resumes += 1
        self._resumed_at_s = at_s
        return (f" (resume {self.resumes} since the first fault {at_s - self.start_s:.1f} s ago; "
                f"after another fault {self.readings_to_resume()} valid readings)")

    def ran_clean(self, time_s: float) -> None:
        """A tick set the heater at ``time_s``: the episode ends once that is a recovery timeout after the
        last resume (the next fault begins a new one)."""
        if self.start_s is not None and time_s - self._resumed_at_s >= self.safety.recovery_timeout_s:
            self.start_s = None
            self.resumes = 0

    # -- asked what to do ----------------------------------------------------------
    def readings_to_resume(self) -> int:
        """Valid readings in a row the loop needs before it resumes: ``safety.valid_readings_to_resume``,
        doubled for every resume since the episode began (at most a recovery timeout's worth)."""
        safety = self.safety
        most = max(safety.valid_readings_to_resume, int(safety.recovery_timeout_s / self.period_s))
        return min(safety.valid_readings_to_resume * 2 ** self.resumes, most)

    def timed_out(self, now_s: float) -> bool:
        """The episode has lasted longer than ``safety.recovery_timeout_s``: stop (no episode under way: no)."""
        return self.start_s is not None and now_s - self.start_s > self.safety.recovery_timeout_s

    def reconnect_due(self, now_s: float) -> bool:
        """Whether to reopen the instruments now (then counted as tried): no valid reading since the fault,
        and the last attempt at least :data:`RECONNECT_INTERVAL_S` ago. Once readings are valid again they
        are counted toward the resume instead."""
        if self._valid_in_a_row == 0 and now_s - self._last_reconnect_s >= RECONNECT_INTERVAL_S:
            self._last_reconnect_s = now_s
            return True
        return False

    def hold_to_report(self) -> bool:
        """Whether a temperature above its limit that holds the heater off is to be said now: once per hold."""
        if self._hold_reported:
            return False
        self._hold_reported = True
        return True
