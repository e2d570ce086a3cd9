"""The physics every simulated heater supply shares: a current source into the flange heater.

The supply drives its programmed current through the heater while the
voltage that takes stays under the compliance limit; beyond it, the output
holds the compliance voltage and the current falls to V/R (an open heater:
no current at all). The power the heater then dissipates, V*I, goes to the
simulated cryostat at the instant of the command that changed it.

Faults (docs/explanation/instruments.md): :meth:`inject_refuse_output` (the interlock or
output enable is open: the output stays off when asked on) and
:meth:`inject_open_heater` (a broken heater wire: infinite resistance).

The supply keeps its own log of the power it delivered,
:attr:`EmulatedCurrentSource.delivered_w`: every change, at the clock instant
it executed the command. That is the heater's power as the instrument saw it,
against which a test holds what the daemon recorded.
"""

from __future__ import annotations

import collections
import math

from simulated_hw.cryostat import SimulatedCryostat
from simulated_hw.instrument import EmulatedInstrument


#: Output changes :attr:`EmulatedCurrentSource.delivered_w` keeps.
DELIVERED_LOG_LENGTH = 100_000


class EmulatedCurrentSource(EmulatedInstrument):
    """A current source whose load is the simulated cryostat's flange heater.

    Parameters
    ----------
    cryostat : SimulatedCryostat
        Where the heater power goes (and whose clock the supply lives on).
    heater_resistance_ohm : float
        Resistance of the flange heater.
    identity : str
        ``*IDN?`` reply.
    """

    def __init__(self, cryostat: SimulatedCryostat, heater_resistance_ohm: float, identity: str):
        if not heater_resistance_ohm > 0.0:
            raise ValueError(f"heater resistance must be positive, got {heater_resistance_ohm}")
        super().__init__(cryostat.clock, identity)
        self.cryostat = cryostat
        self.heater_resistance_ohm = float(heater_resistance_ohm)
        self._sources_current_only = all(getattr(type(self), name) is getattr(EmulatedCurrentSource, name)
                                         for name in ("output_voltage_v", "output_current_a", "in_compliance"))
        self.output_blocked = False
        self.heater_open = False
        self.output_on = False
        self.current_setpoint_a = 0.0
        self.compliance_v = 10.0
        #: What the heater got: (clock time s, power W) at every change of the output, the last
        #: :data:`DELIVERED_LOG_LENGTH` of them (for checks of what really reached the heater, and when).
        self.delivered_w: collections.deque[tuple[float, float]] = collections.deque(maxlen=DELIVERED_LOG_LENGTH)

    # -- faults ----------------------------------------------------------------------
    def inject_refuse_output(self, blocked: bool = True) -> None:
        """Fault: the supply refuses to turn its output on (interlock / output enable open)."""
        with self._lock:
            self.output_blocked = blocked
            if blocked:
                self.output_on = False
            self.apply_to_heater()

    def inject_open_heater(self, is_open: bool = True) -> None:
        """Fault: the heater circuit is open (infinite resistance)."""
        with self._lock:
            self.heater_open = is_open
            self.apply_to_heater()

    # -- the load --------------------------------------------------------------------
    @property
    def load_resistance_ohm(self) -> float:
        return math.inf if self.heater_open else self.heater_resistance_ohm

    @property
    def in_compliance(self) -> bool:
        """The output is voltage-limited: R*I would exceed the compliance."""
        if not self.output_on:
            return False
        return abs(self.current_setpoint_a) * self.load_resistance_ohm > self.compliance_v

    @property
    def output_voltage_v(self) -> float:
        """Voltage across the output terminals (V)."""
        if not self.output_on:
            return 0.0
        if self.in_compliance:
            return math.copysign(self.compliance_v, self.current_setpoint_a)
        return self.current_setpoint_a * self.heater_resistance_ohm

    @property
    def output_current_a(self) -> float:
        """Current actually flowing through the heater (A)."""
        if not self.output_on:
            return 0.0
        if self.in_compliance:
            return self.output_voltage_v / self.load_resistance_ohm
        return self.current_setpoint_a

    @property
    def heater_power_w(self) -> float:
        """Power dissipated in the heater (W): :attr:`output_voltage_v` times :attr:`output_current_a` (for a
        supply that sources current as this class does, the same product with the compliance looked at once)."""
        if not self._sources_current_only:
            return self.output_voltage_v * self.output_current_a
        if not self.output_on:
            return 0.0
        if self.in_compliance:
            voltage = math.copysign(self.compliance_v, self.current_setpoint_a)
            return voltage * (voltage / self.load_resistance_ohm)
        return (self.current_setpoint_a * self.heater_resistance_ohm) * self.current_setpoint_a

    def apply_to_heater(self) -> None:
        """Give the cryostat the heater power of the present output state, from now on."""
        power_w = abs(self.heater_power_w)
        self.cryostat.set_heater_power(power_w)
        if not self.delivered_w or self.delivered_w[-1][1] != power_w:
            self.delivered_w.append((self.clock.now(), power_w))

    def power_at(self, time_s: float) -> float:
        """The power (W) the heater got at clock time ``time_s`` (from the log; 0 before its first entry)."""
        power_w = 0.0
        for instant, logged_w in self.delivered_w:
            if instant > time_s:
                break
            power_w = logged_w
        return power_w

    def first_off_after(self, time_s: float) -> float | None:
        """The first clock time at or after ``time_s`` at which the heater got 0 W (None: not so far)."""
        if self.power_at(time_s) == 0.0:
            return time_s
        return next((instant for instant, power_w in self.delivered_w if instant >= time_s and power_w == 0.0), None)

    def zero_since(self, time_s: float) -> float | None:
        """The first clock time at or after ``time_s`` from which the heater got 0 W for good (so far), or None."""
        changes = list(self.delivered_w)
        if not changes or changes[-1][1] != 0.0:
            return None
        return max(time_s, changes[-1][0])

    def turn_output(self, on: bool) -> bool:
        """Turn the output on or off; False when on was asked but the output is blocked."""
        refused = on and self.output_blocked
        self.output_on = on and not refused
        self.apply_to_heater()
        return not refused

    def set_current(self, current_a: float) -> None:
        self.current_setpoint_a = current_a
        self.apply_to_heater()

    def set_compliance(self, compliance_v: float) -> None:
        self.compliance_v = abs(compliance_v)
        self.apply_to_heater()
