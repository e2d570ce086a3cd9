"""The heater's power limit and the current for a power: one rounding rule for the regulator and the supply.

The regulator holds the heater power within 0 and a maximum; the supply driver
sends I = sqrt(P / R) and refuses a current above I_max. Both must agree to the
last bit: R * I_max**2, computed in floating point, can give a current one
step above I_max (R = 75 ohm, I_max = 30 mA: sqrt(R * I_max**2 / R) =
0.030000000000000002 A), and the driver would refuse the heater's own
maximum. So the maximum power is defined here by the driver's own test:
the largest power whose current, as :func:`current_for_power_a` computes
it, is not above I_max. It differs from R * I_max**2 by at most a few parts
in 10**16; a power above it is still refused, never clipped.

Examples
--------
>>> import math
>>> 75.0 * 0.03 ** 2 <= largest_power_w(75.0, 0.03)
False
>>> current_for_power_a(largest_power_w(75.0, 0.03), 75.0) <= 0.03
True
>>> current_for_power_a(math.nextafter(largest_power_w(75.0, 0.03), math.inf), 75.0) > 0.03
True
"""

from __future__ import annotations

import math


def current_for_power_a(power_w: float, resistance_ohm: float) -> float:
    """The heater current for ``power_w`` (W) through ``resistance_ohm`` (ohm): sqrt(P / R) in A."""
    return math.sqrt(power_w / resistance_ohm)


def largest_power_w(resistance_ohm: float, max_current_a: float) -> float:
    """The largest power (W) whose :func:`current_for_power_a` is not above ``max_current_a`` (A).

    R * I_max**2 moved by the few floating-point steps that make it so.
    """
    if not (resistance_ohm > 0.0 and max_current_a > 0.0 and math.isfinite(resistance_ohm)
            and math.isfinite(max_current_a)):
        raise ValueError(f"a heater limit needs a finite resistance and current above 0, got {resistance_ohm!r} "
                         f"ohm, {max_current_a!r} A")
    power = resistance_ohm * max_current_a ** 2
    while current_for_power_a(power, resistance_ohm) > max_current_a:
        power = math.nextafter(power, 0.0)
    while current_for_power_a(math.nextafter(power, math.inf), resistance_ohm) <= max_current_a:
        power = math.nextafter(power, math.inf)
    return power


__all__ = ["current_for_power_a", "largest_power_w"]
