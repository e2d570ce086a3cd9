"""A simulated Keithley 2400 SourceMeter sourcing current into the flange heater.

SCPI as in the 2400 Series SourceMeter User's Manual (2400S-900-01), section
18, for what the heater driver uses (table in ``docs/instruments.md``):
``:SOURce:FUNCtion CURRent``, ``:SOURce:CURRent:MODE FIXed``,
``:SOURce:CURRent:RANGe``, ``:SOURce:CURRent[:LEVel][:IMMediate][:AMPLitude]``
(-1.05 to 1.05 A), ``:SENSe:FUNCtion "VOLTage"``,
``:SENSe:VOLTage:PROTection[:LEVel]`` (the voltage compliance, -210 to 210 V)
and ``:PROTection:TRIPped?``, ``:SENSe:VOLTage:RANGe``, ``:SENSe:VOLTage:NPLCycles``,
``:SYSTem:RSENse``, ``:FORMat:ELEMents``, ``:OUTPut[:STATe]`` and ``:READ?``.

Errors from the manual's Appendix B: turning the output on while it is
blocked queues ``+802,"OUTPUT blocked by output enable"``; ``:READ?`` with
the output off queues ``+803,"Not permitted with OUTPUT off"`` and sends
nothing.
"""

from __future__ import annotations

from simulated_hw.current_source import EmulatedCurrentSource
from simulated_hw.cryostat import SimulatedCryostat
from simulated_hw.instrument import boolean_setting, on_off
from simulated_hw.scpi import (ILLEGAL_PARAMETER_VALUE, ScpiError, parse_boolean, parse_choice,
                               parse_number, scpi_error, single_argument)

OUTPUT_BLOCKED = (802, "OUTPUT blocked by output enable")
NOT_WITH_OUTPUT_OFF = (803, "Not permitted with OUTPUT off")
CURRENT_RANGES_A = (1e-6, 10e-6, 100e-6, 1e-3, 10e-3, 100e-3, 1.0)
VOLTAGE_RANGES_V = (0.2, 2.0, 20.0, 200.0)
ELEMENTS = ("VOLTage", "CURRent", "RESistance", "TIME", "STATus")


class Keithley2400Emulator(EmulatedCurrentSource):
    """A 2400 in source-current, measure-voltage mode, its output wired to the flange heater."""

    def __init__(self, cryostat: SimulatedCryostat, heater_resistance_ohm: float, *,
                 serial_number: str = "0000001"):
        super().__init__(cryostat, heater_resistance_ohm,
                         f"KEITHLEY INSTRUMENTS INC.,MODEL 2400,{serial_number},C30   Mar 17 2006 09:29:29/A02  /K/J")
        self.reset()
        add = self.commands.add
        add(":SOURce[1]:FUNCtion[:MODE]", write=self._set_source_function, query=lambda args: "CURR")
        add(":SOURce[1]:CURRent:MODE", write=lambda args: parse_choice(args, ("FIXed",)),
            query=lambda args: "FIX")
        add(":SOURce[1]:CURRent:RANGe[:UPPer]", write=self._set_current_range,
            query=lambda args: f"{self.current_range_a:.6E}")
        add(":SOURce[1]:CURRent[:LEVel][:IMMediate][:AMPLitude]",
            write=lambda args: self.set_current(parse_number(args, -1.05, 1.05, default=0.0)),
            query=lambda args: f"{self.current_setpoint_a:.6E}")
        add("[:SENSe[1]]:FUNCtion[:ON]", write=self._set_sense_function, query=lambda args: '"VOLT:DC"')
        write, query = boolean_setting(self, "concurrent")
        add("[:SENSe[1]]:FUNCtion:CONCurrent", write=write, query=query)
        add("[:SENSe[1]]:VOLTage[:DC]:PROTection[:LEVel]",
            write=lambda args: self.set_compliance(parse_number(args, -210.0, 210.0, default=21.0)),
            query=lambda args: f"{self.compliance_v:.6E}")
        add("[:SENSe[1]]:VOLTage[:DC]:PROTection:TRIPped", query=lambda args: on_off(self.in_compliance))
        add("[:SENSe[1]]:VOLTage[:DC]:RANGe[:UPPer]", write=self._set_voltage_range,
            query=lambda args: f"{self.voltage_range_v:.6E}")
        add("[:SENSe[1]]:VOLTage[:DC]:NPLCycles",
            write=lambda args: setattr(self, "nplc", parse_number(args, 0.01, 10.0, default=1.0)),
            query=lambda args: f"{self.nplc:g}")
        write, query = boolean_setting(self, "four_wire")
        add(":SYSTem:RSENse", write=write, query=query)
        add(":FORMat:ELEMents[:SENSe[1]]", write=self._set_elements,
            query=lambda args: ",".join(e[:4].upper() for e in ELEMENTS if e.upper() in self.elements))
        add(":OUTPut[1][:STATe]", write=self._set_output, query=lambda args: on_off(self.output_on))
        add(":SOURce[1]:CLEar[:IMMediate]", write=lambda args: self.turn_output(False))
        add(":READ", query=self._read)

    def reset(self) -> None:
        self.output_on = False
        self.current_setpoint_a = 0.0
        self.current_range_a = 1e-6
        self.compliance_v = 21.0
        self.voltage_range_v = 20.0
        self.nplc = 1.0
        self.concurrent = True
        self.four_wire = False
        self.elements = tuple(e.upper() for e in ELEMENTS)
        self.apply_to_heater()

    def _set_source_function(self, args: list[str]) -> None:
        if parse_choice(args, ("CURRent", "VOLTage", "MEMory")) != "CURRENT":
            raise scpi_error(ILLEGAL_PARAMETER_VALUE)

    def _set_sense_function(self, args: list[str]) -> None:
        text = single_argument(args).strip().strip("'\"").upper()
        if text not in ("VOLT", "VOLTAGE", "VOLT:DC", "VOLTAGE:DC"):
            raise scpi_error(ILLEGAL_PARAMETER_VALUE)

    def _set_current_range(self, args: list[str]) -> None:
        expected = abs(parse_number(args, -1.05, 1.05, default=1e-6))
        self.current_range_a = next(r for r in CURRENT_RANGES_A if expected <= r * 1.05)

    def _set_voltage_range(self, args: list[str]) -> None:
        expected = abs(parse_number(args, -210.0, 210.0, default=21.0))
        self.voltage_range_v = next(r for r in VOLTAGE_RANGES_V if expected <= r * 1.05)

    def _set_elements(self, args: list[str]) -> None:
        chosen = {parse_choice([arg], ELEMENTS) for arg in args}
        self.elements = tuple(e.upper() for e in ELEMENTS if e.upper() in chosen)

    def _set_output(self, args: list[str]) -> None:
        if not self.turn_output(parse_boolean(args)):
            raise ScpiError(*OUTPUT_BLOCKED)

    def _read(self, args: list[str]) -> str:
        if not self.output_on:
            raise ScpiError(*NOT_WITH_OUTPUT_OFF)
        values = {"VOLTAGE": self.output_voltage_v, "CURRENT": self.output_current_a,
                  "RESISTANCE": 9.91e37, "TIME": self.clock.now(),
                  "STATUS": float(8 if self.in_compliance else 0)}
        return ",".join(f"{values[element]:+.6E}" for element in self.elements)
