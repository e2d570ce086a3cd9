"""Keithley 6221 AC and DC current source as the flange heater supply.

Commands from the Model 6220/6221 Reference Manual (622x-901-01), section
"SOURce subsystem" and section 11 "Status Structure"; every string sent is
listed in ``docs/explanation/instruments.md``.

The 6221 cannot measure its output voltage: the read-back current is the
programmed one and the voltage is I R with the configured heater resistance
(``voltage_measured=False``). Compliance and the interlock come from the
measurement condition register (``:STATus:MEASurement:CONDition?``, Figure
11-6): bit B3 "Compliance", bit B1 "Interlock asserted".

Examples
--------
>>> from drivers.clock import VirtualClock
>>> from cryod.model import load_model
>>> from drivers.transports import InProcessTransport
>>> from simulated_hw.cryostat import SimulatedCryostat
>>> from simulated_hw.keithley6221 import Keithley6221Emulator
>>> clock = VirtualClock()
>>> cryostat = SimulatedCryostat(load_model(), clock, seed=1)
>>> transport = InProcessTransport(Keithley6221Emulator(cryostat, heater_resistance_ohm=50.0))
>>> with Keithley6221(transport, clock, heater_resistance_ohm=50.0, voltage_compliance_v=10.0) as heater:
...     setting = heater.set_power_w(0.110)
...     round(setting.current_a * 1e3, 3), round(cryostat.heater_power_w, 6)
(46.904, 0.11)
>>> cryostat.heater_power_w
0.0
"""

from __future__ import annotations

from drivers.errors import BadReply, HeaterRefused
from drivers.heater import HeaterReadback, HeaterSupply
from drivers.scpi import Control, number, on_off, parse_bool

COMPLIANCE_BIT = 1 << 3
INTERLOCK_ASSERTED_BIT = 1 << 1


class Keithley6221(HeaterSupply):
    """Driver of a Keithley 6221 sourcing the heater current (see :class:`drivers.heater.HeaterSupply`)."""

    expected_model = "MODEL 6221"
    supply_max_current_a = 0.105
    supply_compliance_range_v = (0.1, 105.0)

    source_current_a = Control(":SOURce:CURRent {}", ":SOURce:CURRent?",
                               "DC output current in A, -105e-3 to 105e-3 (SOURce:CURRent[:LEVel]...).",
                               number(-0.105, 0.105, "A", "{:.6E}"), float)
    source_autorange = Control(":SOURce:CURRent:RANGe:AUTO {}", ":SOURce:CURRent:RANGe:AUTO?",
                               "Source autorange on/off.", on_off, parse_bool)
    source_range_a = Control(":SOURce:CURRent:RANGe {}", ":SOURce:CURRent:RANGe?",
                             "Source range in A: the lowest range holding the value (2 nA to 100 mA).",
                             number(0.0, 0.105, "A", "{:.6E}"), float)
    compliance_v = Control(":SOURce:CURRent:COMPliance {}", ":SOURce:CURRent:COMPliance?",
                           "Voltage compliance in V, 0.1 to 105 (SOURce:CURRent:COMPliance).",
                           number(0.1, 105.0, "V", "{:.2f}"), float)

    def configure_source(self) -> None:
        self.write("*CLS")
        self.output_enabled = False
        self.source_autorange = False
        self.source_range_a = self.max_current_a
        self.compliance_v = self.voltage_compliance_v
        self.source_current_a = 0.0
        self.check_error_queue("current source configuration")

    #: The measurement condition register (bits: B1 interlock asserted, B3 compliance).
    compliance_query = ":STATus:MEASurement:CONDition?"

    def _condition_from_reply(self, reply: str) -> int:
        try:
            return int(float(reply))
        except ValueError:
            raise BadReply(self.label, f"measurement condition register: reply to {self.compliance_query} "
                                       "is not a number", reply=reply) from None

    def measurement_condition(self) -> int:
        """The measurement condition register (bits: B1 interlock asserted, B3 compliance)."""
        return self._condition_from_reply(self.query(self.compliance_query))

    def compliance_from_reply(self, reply: str) -> bool:
        return bool(self._condition_from_reply(reply) & COMPLIANCE_BIT)

    def output_off_reason(self, compliance_reply: str) -> str:
        condition = self._condition_from_reply(compliance_reply)
        if not condition & INTERLOCK_ASSERTED_BIT:
            return f"interlock not asserted, measurement condition {condition}"
        return f"interlock asserted: turned off at the supply, measurement condition {condition}"

    def output_refused(self) -> HeaterRefused:
        condition = self.measurement_condition()
        why = "interlock not asserted" if not condition & INTERLOCK_ASSERTED_BIT else "output did not turn on"
        return HeaterRefused(self.label, f"output refused: {why} (measurement condition {condition})")


    def measure_output(self) -> HeaterReadback:
        current = self.query_number(":SOURce:CURRent?", "output current")
        self.check_compliance()
        if not self.output_is_on:
            current = 0.0
        voltage = current * self.heater_resistance_ohm
        return HeaterReadback(current, voltage, voltage * current, voltage_measured=False)
