"""The setpoint ramp: a setpoint that moves toward its target at a limited rate (K/min)."""

from __future__ import annotations

import math


class SetpointRamp:
    """A setpoint that moves toward its target at a limited rate.

    Parameters
    ----------
    setpoint_K : float
        Starting setpoint.
    rate_K_per_min : float
        Ramp rate; 0 means jump at once.

    Examples
    --------
    >>> ramp = SetpointRamp(4.5, rate_K_per_min=0.6)
    >>> ramp.target_K = 5.0
    >>> round(ramp.advance(30.0), 3)     # 30 s at 0.01 K/s
    4.8
    """

    def __init__(self, setpoint_K: float, rate_K_per_min: float = 0.0):
        if rate_K_per_min < 0.0 or not math.isfinite(rate_K_per_min):
            raise ValueError(f"ramp rate must be >= 0 K/min, got {rate_K_per_min}")
        self.setpoint_K = float(setpoint_K)
        self.target_K = float(setpoint_K)
        self.rate_K_per_min = float(rate_K_per_min)

    @property
    def ramping(self) -> bool:
        return self.setpoint_K != self.target_K

    def advance(self, dt_s: float) -> float:
        """Move toward the target for ``dt_s`` seconds; returns the setpoint (K)."""
        if self.rate_K_per_min == 0.0:
            self.setpoint_K = self.target_K
            return self.setpoint_K
        step = self.rate_K_per_min / 60.0 * dt_s
        difference = self.target_K - self.setpoint_K
        self.setpoint_K = self.target_K if abs(difference) <= step else self.setpoint_K + math.copysign(step, difference)
        return self.setpoint_K
