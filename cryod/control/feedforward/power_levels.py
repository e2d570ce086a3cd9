"""The levels the feedforward's waveform rides on: the feedback terms' power, PI's mean power, T2's distance to go.

* The feedback terms' power (PI's), smoothed over :data:`BASE_TIME_S`: the level the waveform rides
  on, around which the heater's room is counted (the waveform and the probe are held within 0 W and
  R I_max^2 about it).
* At every learning step, that power smoothed again over :data:`MEAN_POWER_TIME_S` and T2's distance
  from the setpoint over :data:`SETTLING_TIME_S`: T2 settled at the setpoint (within
  :data:`SETTLED_K`), the mean power is the one the setpoint needs on this cryostat, and the limit
  may be computed from what was learned; T2 still on its way (beyond :data:`APPROACHING_K`), the
  probe may be larger.

Examples
--------
>>> levels = PowerLevels()
>>> for _ in range(100):
...     levels.follow_others(0.113, 0.08)
>>> levels.follow_mean(1e-4, 2.0)
>>> levels.other_terms_w, levels.mean_power_w, levels.settled, levels.approaching
(0.113, 0.113, True, False)
"""

from __future__ import annotations

import math

#: Smoothing of the feedback terms' power, the level the waveform rides on (s).
BASE_TIME_S = 2.0
#: Smoothing of PI's power for the mean power the setpoint needs (s), and of T2's distance from the setpoint.
MEAN_POWER_TIME_S = 60.0
SETTLING_TIME_S = 20.0
#: T2 is taken as settled at the setpoint (its mean power the one the setpoint needs) within this (K) ...
SETTLED_K = 2e-4
#: ... and as still on its way to it (the probe may be larger) beyond this (K).
APPROACHING_K = 2e-3


class PowerLevels:
    """The feedback terms' power and its mean, T2's distance from the setpoint, smoothed (module notes)."""

    def __init__(self) -> None:
        #: The feedback terms' power, smoothed over :data:`BASE_TIME_S` (W; None before the first tick).
        self.other_terms_w: float | None = None
        #: ... and over :data:`MEAN_POWER_TIME_S` at the learning steps (W; None before the first).
        self.mean_power_w: float | None = None
        #: T2's distance from the setpoint, smoothed over :data:`SETTLING_TIME_S` at the learning steps (K).
        self.setpoint_distance_K = math.inf

    def follow_others(self, others_w: float, period_s: float) -> None:
        """Every closed-loop tick: the feedback terms' power now (W)."""
        if self.other_terms_w is None:
            self.other_terms_w = others_w
        else:
            self.other_terms_w += (others_w - self.other_terms_w) * min(period_s / BASE_TIME_S, 1.0)

    def follow_mean(self, distance_K: float, interval_s: float) -> None:
        """At every learning step: T2's distance from the setpoint now (K); ``interval_s`` between steps."""
        if self.other_terms_w is not None:
            self.mean_power_w = self.other_terms_w if self.mean_power_w is None else \
                self.mean_power_w + (self.other_terms_w - self.mean_power_w) * min(interval_s / MEAN_POWER_TIME_S, 1.0)
        if not math.isfinite(self.setpoint_distance_K):
            self.setpoint_distance_K = distance_K
        elif math.isfinite(distance_K):
            self.setpoint_distance_K += (distance_K - self.setpoint_distance_K) * min(interval_s / SETTLING_TIME_S,
                                                                                       1.0)

    @property
    def settled(self) -> bool:
        """T2 at the setpoint, with a mean power: the one the setpoint needs."""
        return self.setpoint_distance_K < SETTLED_K and self.mean_power_w is not None

    @property
    def approaching(self) -> bool:
        """T2 still on its way to the setpoint."""
        return self.setpoint_distance_K > APPROACHING_K


__all__ = ["APPROACHING_K", "BASE_TIME_S", "MEAN_POWER_TIME_S", "PowerLevels", "SETTLED_K", "SETTLING_TIME_S"]
