"""A simulated Keithley 6221 current source driving the flange heater.

SCPI as in the Model 6220/6221 Reference Manual (622x-901-01), for what the
heater driver uses (table in ``docs/explanation/instruments.md``):

* ``[:SOURce[1]]:CURRent[:LEVel][:IMMediate][:AMPLitude] <n>``: -105e-3 to 105e-3 A;
* ``[:SOURce[1]]:CURRent:RANGe <n>`` (2 nA to 100 mA ranges) and ``:RANGe:AUTO <b>``;
* ``[:SOURce[1]]:CURRent:COMPliance <n>``: 0.1 to 105 V (specifications, "VOLTAGE LIMIT");
* ``:OUTPut[:STATe] <b>``, ``[:SOURce[1]]:CLEar[:IMMediate]`` (output off);
* ``:OUTPut:LTEarth <b>`` (output low connected to earth, else floating) and
  ``:OUTPut:ISHield OLOW|GUARd`` (inner shield of the triax output), both
  state only: the simulated heater has no earth path;
* ``[:SOURce[1]]:DELay <n>``: 1e-3 to 999999.999 s, the source delay of
  the trigger model (stored; the DC output here takes no trigger model);
* the measurement condition register (``:STATus:MEASurement:CONDition?``
  and its event and enable registers, shared in :mod:`simulated_hw.status`):
  bit B1 interlock asserted, B3 compliance (section 11, Figure 11-6
  "Measurement event status").

A refused output (interlock open) leaves the output off with the interlock
bit clear; the manual gives no error-queue number for it, so none is queued.
"""

from __future__ import annotations

from simulated_hw.current_source import EmulatedCurrentSource
from simulated_hw.cryostat import SimulatedCryostat
from simulated_hw.instrument import boolean_setting, on_off
from simulated_hw.scpi import parse_boolean, parse_choice, parse_number, short_form

#: Source ranges of the 622x (A).
CURRENT_RANGES_A = (2e-9, 20e-9, 200e-9, 2e-6, 20e-6, 200e-6, 2e-3, 20e-3, 100e-3)
MAXIMUM_CURRENT_A = 0.105
INTERLOCK_ASSERTED_BIT = 1 << 1
COMPLIANCE_BIT = 1 << 3
#: Source delay limits (s); ``*RST`` sets the shortest.
MINIMUM_SOURCE_DELAY_S = 1e-3
MAXIMUM_SOURCE_DELAY_S = 999999.999
#: Where the triax inner shield goes: output low, or guard.
SHIELDS = ("OLOW", "GUARd")


class Keithley6221Emulator(EmulatedCurrentSource):
    """A 6221 whose output is wired to the simulated flange heater."""

    def __init__(self, cryostat: SimulatedCryostat, heater_resistance_ohm: float, *,
                 serial_number: str = "0000001"):
        super().__init__(cryostat, heater_resistance_ohm,
                         f"KEITHLEY INSTRUMENTS INC.,MODEL 6221,{serial_number},A01  /A02")
        self.reset()
        add = self.commands.add
        source = "[:SOURce[1]]:CURRent"
        add(source + "[:LEVel][:IMMediate][:AMPLitude]",
            write=lambda args: self.set_current(parse_number(args, -MAXIMUM_CURRENT_A, MAXIMUM_CURRENT_A,
                                                             default=0.0)),
            query=lambda args: f"{self.current_setpoint_a:.6E}")
        add(source + ":RANGe", write=self._set_range, query=lambda args: f"{self.range_a:.6E}")
        write, query = boolean_setting(self, "autorange")
        add(source + ":RANGe:AUTO", write=write, query=query)
        add(source + ":COMPliance", write=lambda args: self.set_compliance(parse_number(args, 0.1, 105.0,
                                                                                        default=10.0)),
            query=lambda args: f"{self.compliance_v:.2f}")
        add(":OUTPut[:STATe]", write=lambda args: self.turn_output(parse_boolean(args)),
            query=lambda args: on_off(self.output_on))
        add("[:SOURce[1]]:CLEar[:IMMediate]", write=lambda args: self.turn_output(False))
        write, query = boolean_setting(self, "low_to_earth")
        add(":OUTPut:LTEarth", write=write, query=query)
        add(":OUTPut:ISHield", write=lambda args: setattr(self, "inner_shield", parse_choice(args, SHIELDS)),
            query=lambda args: short_form(next(s for s in SHIELDS if s.upper() == self.inner_shield)))
        add("[:SOURce[1]]:DELay", write=lambda args: setattr(self, "source_delay_s", parse_number(
            args, MINIMUM_SOURCE_DELAY_S, MAXIMUM_SOURCE_DELAY_S, default=MINIMUM_SOURCE_DELAY_S)),
            query=lambda args: f"{self.source_delay_s:.6E}")

    def reset(self) -> None:
        self.output_on = False
        self.current_setpoint_a = 0.0
        self.compliance_v = 10.0
        self.range_a = 2e-3
        self.autorange = False
        self.low_to_earth = False
        self.inner_shield = "OLOW"
        self.source_delay_s = MINIMUM_SOURCE_DELAY_S
        self.apply_to_heater()

    def _set_range(self, args: list[str]) -> None:
        expected = abs(parse_number(args, -MAXIMUM_CURRENT_A, MAXIMUM_CURRENT_A, default=2e-3))
        self.range_a = next(r for r in CURRENT_RANGES_A if expected <= r * 1.05)
        self.autorange = False

    @property
    def measurement_condition(self) -> int:
        """Measurement condition register: interlock asserted (B1), compliance (B3)."""
        value = 0 if self.output_blocked else INTERLOCK_ASSERTED_BIT
        if self.in_compliance:
            value |= COMPLIANCE_BIT
        return value
