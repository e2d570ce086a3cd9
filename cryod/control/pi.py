"""PI control of the flange temperature, output in heater power (W): the ``pi`` control term.

``power = Kp * e + integral``, ``integral += Ki * e * dt``, with e = setpoint - T2
in K, Kp in W/K and Ki in W/(K s). The controller is one term of the heater
power; the regulator (:mod:`cryod.control.regulator`) adds the terms, holds the
total within the heater's limits and tells every term what was applied
(:meth:`PiController.limit`), so the integral does not wind up against a limit.

Bumpless by construction: changing gains, or closing the loop from a heater
power that was set by hand, keeps the output where it was.

Configuration, section ``control.pi`` (reloadable)::

    pi:
      proportional_W_per_K: 10.0
      integral_W_per_K_s: 0.2

Examples
--------
>>> pi = PiController(PiGains(proportional_w_per_K=0.5, integral_w_per_K_s=0.02), output_max_w=0.5)
>>> round(pi.update(measured_K=4.9, setpoint_K=5.0, dt_s=0.08), 4)
0.0502
>>> pi.limit(requested_w=0.0502, applied_w=0.0502)
>>> pi.set_gains(PiGains(1.0, 0.02))      # bumpless: output unchanged
>>> round(pi.output_w, 4)
0.0502
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cryod.control.terms import ControlTerm, TickInputs
from cryod.records.columns import Column
from cryod.yaml_source import Section

#: Largest Kp (W/K) and Ki (W/(K s)) a configuration takes.
MAX_GAIN = 1000.0


@dataclass(frozen=True)
class PiGains:
    """PI gains in SI units.

    Attributes
    ----------
    proportional_w_per_K : float
        Kp: heater watts per kelvin of error.
    integral_w_per_K_s : float
        Ki: heater watts per kelvin-second of accumulated error
        (integral time Ti = Kp / Ki).
    """

    proportional_w_per_K: float
    integral_w_per_K_s: float

    def __post_init__(self):
        for name in ("proportional_w_per_K", "integral_w_per_K_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value}")


class PiController:
    """PI with anti-windup and bumpless transfer.

    Parameters
    ----------
    gains : PiGains
    output_min_w, output_max_w : float
        Range of the heater power (W): 0 to R * I_max**2.
    """

    def __init__(self, gains: PiGains, output_min_w: float = 0.0, output_max_w: float = math.inf):
        if not output_max_w > output_min_w >= 0.0:
            raise ValueError(f"need 0 <= output_min_w < output_max_w, got {output_min_w}, {output_max_w}")
        self.gains = gains
        self.output_min_w = float(output_min_w)
        self.output_max_w = float(output_max_w)
        self.integral_w = 0.0
        self.proportional_w = 0.0
        self.error_K = 0.0
        self.output_w = 0.0
        self._last_increment_w = 0.0

    # -- transfers ---------------------------------------------------------
    def set_automatic(self, measured_K: float, setpoint_K: float, present_power_w: float | None = None) -> None:
        """Take over without a bump: the next output continues from ``present_power_w``.

        Parameters
        ----------
        measured_K, setpoint_K : float
            Present flange temperature and setpoint.
        present_power_w : float, optional
            The heater power from this term now (default: the last output).
        """
        power = self.output_w if present_power_w is None else float(present_power_w)
        self.error_K = setpoint_K - measured_K
        self.proportional_w = self.gains.proportional_w_per_K * self.error_K
        self.integral_w = power - self.proportional_w
        self.output_w = power

    def set_gains(self, gains: PiGains) -> None:
        """New gains, keeping the present output (bumpless).

        The integral takes whatever value keeps Kp * e + integral unchanged,
        even outside its usual range; integration then moves it back.
        """
        new_proportional = gains.proportional_w_per_K * self.error_K
        self.integral_w = self.integral_w + self.proportional_w - new_proportional
        self.gains = gains
        self.proportional_w = new_proportional

    def set_output_limits(self, output_min_w: float, output_max_w: float) -> None:
        """Change the heater power range (W)."""
        if not output_max_w > output_min_w >= 0.0:
            raise ValueError(f"need 0 <= output_min_w < output_max_w, got {output_min_w}, {output_max_w}")
        self.output_min_w, self.output_max_w = float(output_min_w), float(output_max_w)
        self.integral_w = self._clamped_integral(self.integral_w)

    def _integral_bounds(self) -> tuple[float, float]:
        """Range the integral may grow into: down to minus the output span (room to offset a
        proportional part), up to the output maximum."""
        return self.output_min_w - (self.output_max_w - self.output_min_w), self.output_max_w

    def _clamped_integral(self, value: float) -> float:
        low, high = self._integral_bounds()
        return min(max(value, low), high)

    # -- the cycle -----------------------------------------------------------
    def update(self, measured_K: float, setpoint_K: float, dt_s: float) -> float:
        """This term's heater power (W) for the coming period.

        Parameters
        ----------
        measured_K : float
            Flange temperature now.
        setpoint_K : float
            Setpoint now (after any ramp).
        dt_s : float
            Time since the previous update (s).
        """
        self.error_K = setpoint_K - measured_K
        self.proportional_w = self.gains.proportional_w_per_K * self.error_K
        previous = self.integral_w
        integral = previous + self.gains.integral_w_per_K_s * self.error_K * dt_s
        low, high = self._integral_bounds()
        # never grows further out of its bounds; never pulled back to them at once
        if integral > high and integral > previous:
            integral = max(previous, high)
        elif integral < low and integral < previous:
            integral = min(previous, low)
        self.integral_w = integral
        self._last_increment_w = self.integral_w - previous
        self.output_w = self.proportional_w + self.integral_w
        return self.output_w

    def limit(self, requested_w: float, applied_w: float) -> None:
        """Anti-windup: the loop applied ``applied_w`` of a requested total ``requested_w``.

        When the total was held at a limit and this cycle's integration pushed
        further into it, that integration is undone.
        """
        held_high = applied_w < requested_w and self._last_increment_w > 0.0
        held_low = applied_w > requested_w and self._last_increment_w < 0.0
        if held_high or held_low:
            self.integral_w -= self._last_increment_w
            self._last_increment_w = 0.0
            self.output_w = self.proportional_w + self.integral_w


class PiTerm(ControlTerm):
    """PI feedback on the flange temperature, as a control term (section ``control.pi``).

    Parameters
    ----------
    gains : PiGains
    output_max : float
        Upper limit of the regulator's output (W; A for a current-output study).
    """

    name = "pi"
    required = True
    columns = (Column("pi_proportional_W", "W", "PI proportional part, Kp * (setpoint - T2)", "{:.6e}"),
               Column("pi_integral_W", "W", "PI integral part", "{:.6e}"))

    def __init__(self, gains: PiGains, output_max: float):
        self.controller = PiController(gains, 0.0, output_max)

    @staticmethod
    def settings_from(section: Section | None) -> PiGains:
        """The gains from ``control.pi`` (a required section: never None from :func:`term_settings_from`)."""
        if section is None:
            raise TypeError("control.pi is a required section")
        gains = PiGains(section.number("proportional_W_per_K", minimum=0.0, maximum=MAX_GAIN),
                        section.number("integral_W_per_K_s", minimum=0.0, maximum=MAX_GAIN))
        section.finish()
        return gains

    def reconfigure(self, gains: PiGains, output_max: float) -> None:
        """New gains and output range, bumplessly."""
        self.controller.set_output_limits(0.0, output_max)
        self.controller.set_gains(gains)

    def start(self, tick: TickInputs, present_output: float) -> None:
        # bumpless against the present temperature; a setpoint step then acts through Kp as usual
        self.controller.set_automatic(tick.flange_feedback_K, tick.flange_feedback_K, present_output)

    def update(self, tick: TickInputs) -> float:
        return self.controller.update(tick.flange_feedback_K, tick.setpoint_K, tick.dt_s)

    def limit(self, requested: float, applied: float) -> None:
        self.controller.limit(requested, applied)

    def column_values(self) -> tuple[float, ...]:
        return self.controller.proportional_w, self.controller.integral_w
