"""The setpoint ramp: a setpoint that moves toward its target at a limited rate (K/min)."""

from __future__ import annotations

import math

#: Slowest ramp rate other than 0 (steps), K/min: a microkelvin a minute, slower than anything a
#: measurement could tell from a constant setpoint. It keeps every tick moving the setpoint: at the
#: shortest loop period a configuration takes (0.01 s) the step is 1.7e-10 K, four thousand times
#: the spacing of floating-point numbers at 400 K, the highest limit a configuration takes. A rate
#: like 1e-320 K/min would add nothing to the setpoint and leave it where the loop closed.
MIN_RATE_K_PER_MIN = 1e-6


def rate_refusal(rate_K_per_min: float) -> str | None:
    """Why ``rate_K_per_min`` cannot be a ramp rate, or None when it can (0, or at least the minimum).

    Examples
    --------
    >>> rate_refusal(0.5) is None and rate_refusal(0.0) is None
    True
    >>> rate_refusal(1e-320)
    '1e-320 K/min is too slow to move the setpoint: give 0 for steps or at least 1e-06 K/min'
    """
    if not math.isfinite(rate_K_per_min) or rate_K_per_min < 0.0:
        return f"{rate_K_per_min!r} K/min is not a ramp rate: give 0 for steps or a rate above 0"
    if 0.0 < rate_K_per_min < MIN_RATE_K_PER_MIN:
        return (f"{rate_K_per_min!r} K/min is too slow to move the setpoint: give 0 for steps or at least "
                f"{MIN_RATE_K_PER_MIN:g} K/min")
    return None


class SetpointRamp:
    """A setpoint that moves toward its target at a limited rate.

    Parameters
    ----------
    setpoint_K : float
        Starting setpoint.
    rate_K_per_min : float
        Ramp rate; 0 means jump at once, otherwise at least :data:`MIN_RATE_K_PER_MIN`.

    Examples
    --------
    >>> ramp = SetpointRamp(4.5, rate_K_per_min=0.6)
    >>> ramp.target_K = 5.0
    >>> round(ramp.advance(30.0), 3)     # 30 s at 0.01 K/s
    4.8
    """

    def __init__(self, setpoint_K: float, rate_K_per_min: float = 0.0):
        self.setpoint_K = float(setpoint_K)
        self.target_K = float(setpoint_K)
        self.rate_K_per_min = rate_K_per_min

    @property
    def rate_K_per_min(self) -> float:
        """Ramp rate (K/min); setting one that :func:`rate_refusal` refuses raises ValueError."""
        return self._rate_K_per_min

    @rate_K_per_min.setter
    def rate_K_per_min(self, rate_K_per_min: float) -> None:
        refusal = rate_refusal(rate_K_per_min)
        if refusal is not None:
            raise ValueError(refusal)
        self._rate_K_per_min = float(rate_K_per_min)

    @property
    def ramping(self) -> bool:
        return self.setpoint_K != self.target_K

    def advance(self, dt_s: float) -> float:
        """Move toward the target for ``dt_s`` seconds; returns the setpoint (K)."""
        rate = self._rate_K_per_min
        if rate == 0.0:
            self.setpoint_K = self.target_K
            return self.setpoint_K
        step = rate / 60.0 * dt_s
        difference = self.target_K - self.setpoint_K
        self.setpoint_K = self.target_K if abs(difference) <= step else self.setpoint_K + math.copysign(step, difference)
        return self.setpoint_K
