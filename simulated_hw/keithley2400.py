"""A simulated Keithley 2400 SourceMeter whose output drives the flange heater.

SCPI as in the 2400 Series SourceMeter User's Manual (2400S-900-01),
sections 17 and 18, for what the heater driver uses (table in
``docs/explanation/instruments.md``) and what a lab's own scripts send (PyMeasure's
``Keithley2400``):

* source: ``:SOURce:FUNCtion[:MODE] VOLTage|CURRent`` (``*RST``: VOLTage),
  ``:SOURce:CURRent|VOLTage[:LEVel][:IMMediate][:AMPLitude]`` (-1.05 to
  1.05 A, -210 to 210 V), ``:MODE FIXed``, ``:RANGe[:UPPer]``,
  ``:RANGe:AUTO``; ``:SOURce:DELay`` (0 to 999.9999 s) and ``:DELay:AUTO``;
  ``:SOURce:CLEar[:IMMediate]`` and ``:SOURce:CLEar:AUTO`` (auto output-off);
* sense: ``[:SENSe]:FUNCtion[:ON] "VOLTage"|"CURRent"``,
  ``:FUNCtion:OFF``, ``:FUNCtion[:ON]:ALL``, ``:FUNCtion:CONCurrent``;
  per function ``:PROTection[:LEVel]`` (the compliance: voltage when
  sourcing current, current when sourcing voltage) and
  ``:PROTection:TRIPped?``, ``:RANGe[:UPPer]``, ``:RANGe:AUTO``,
  ``:NPLCycles`` (one setting for all functions);
* ``:SYSTem:RSENse``, ``:SYSTem:AZERo[:STATe] ON|OFF|ONCE``,
  ``:ROUTe:TERMinals FRONt|REAR``, ``:FORMat:ELEMents[:SENSe]``,
  ``:OUTPut[:STATe]``;
* readings: ``:READ?``, ``:MEASure[:VOLTage|:CURRent]?`` (``:CONFigure``
  then ``:READ?``, section 17), ``:CONFigure:<function>``, ``:CONFigure?``,
  ``:ABORt``;
* the measurement condition register: B11 output enable asserted, B14
  compliance (section 15, Figure 15-6).

A reading has the elements of ``:FORMat:ELEMents`` in the order voltage,
current, resistance, time, status. A function that is measured gives its
measured value; the sourced function that is not measured gives its
programmed level (section 18, "Data elements": in the manual's example the
current of a source-I measure-V reading "is the current source value");
anything else reads ``+9.91E+37`` (not a number). The status element is the
manual's status word with the bits this emulation knows: B2 front
terminals, B3 in compliance, B11 voltage measured, B12 current measured,
B14 sourcing voltage, B15 sourcing current, B22 remote sense.

``:CONFigure:<function>`` (and so ``:MEASure:<function>?``) selects the
function alone, returns "all controls related to the selected function"
(its range, autorange and protection, i.e. the compliance) to their
``*RST`` values and turns the output on (Table 17-1: "Output turns on").
With auto output-off (``:SOURce:CLEar:AUTO ON``) ``:READ?`` turns the
output on for the reading and off after it.

Errors from the manual's Appendix B: turning the output on while it is
blocked queues ``+802,"OUTPUT blocked by output enable"``; ``:READ?`` with
the output off (auto output-off disabled) queues ``+803,"Not permitted
with OUTPUT off"`` and sends nothing.
"""

from __future__ import annotations

import math

from simulated_hw.current_source import EmulatedCurrentSource
from simulated_hw.cryostat import SimulatedCryostat
from simulated_hw.instrument import boolean_setting, on_off
from simulated_hw.scpi import (ILLEGAL_PARAMETER_VALUE, ScpiError, parse_boolean, parse_choice, parse_number,
                               scpi_error, short_form, single_argument)

OUTPUT_BLOCKED = (802, "OUTPUT blocked by output enable")
NOT_WITH_OUTPUT_OFF = (803, "Not permitted with OUTPUT off")
CURRENT_RANGES_A = (1e-6, 10e-6, 100e-6, 1e-3, 10e-3, 100e-3, 1.0)
VOLTAGE_RANGES_V = (0.2, 2.0, 20.0, 200.0)
ELEMENTS = ("VOLTage", "CURRent", "RESistance", "TIME", "STATus")
#: What a reading element without a value reads (the manual's NAN).
NOT_A_NUMBER = 9.91e37
#: ``*RST`` values of the two functions: (range, protection).
DEFAULT_VOLTAGE_RANGE_V, DEFAULT_VOLTAGE_PROTECTION_V = 21.0, 21.0
DEFAULT_CURRENT_RANGE_A, DEFAULT_CURRENT_PROTECTION_A = 105e-6, 105e-6
MAXIMUM_SOURCE_DELAY_S = 999.9999
# measurement condition register bits (Figure 15-6)
OUTPUT_ENABLE_ASSERTED_BIT = 1 << 11
COMPLIANCE_BIT = 1 << 14
# status word bits (section 18, "STATus" data element)
STATUS_FRONT_TERMINALS = 1 << 2
STATUS_COMPLIANCE = 1 << 3
STATUS_VOLTAGE_MEASURED = 1 << 11
STATUS_CURRENT_MEASURED = 1 << 12
STATUS_SOURCING_VOLTAGE = 1 << 14
STATUS_SOURCING_CURRENT = 1 << 15
STATUS_REMOTE_SENSE = 1 << 22

FUNCTIONS = ("VOLTage", "CURRent")
#: How :SENSe:FUNCtion? names the functions.
FUNCTION_REPLY = {"VOLTAGE": '"VOLT:DC"', "CURRENT": '"CURR:DC"'}


def _lowest_range(ranges: tuple[float, ...], value: float) -> float:
    return next(r for r in ranges if abs(value) <= r * 1.05)


class Keithley2400Emulator(EmulatedCurrentSource):
    """A 2400 sourcing current (or voltage) into the flange heater and measuring it."""

    def __init__(self, cryostat: SimulatedCryostat, heater_resistance_ohm: float, *,
                 serial_number: str = "0000001"):
        super().__init__(cryostat, heater_resistance_ohm,
                         f"KEITHLEY INSTRUMENTS INC.,MODEL 2400,{serial_number},C30   Mar 17 2006 09:29:29/A02  /K/J")
        self.reset()
        self._register_source_commands()
        self._register_sense_commands()
        add = self.commands.add
        self._add_boolean(":SYSTem:RSENse", "four_wire")
        add(":SYSTem:AZERo[:STATe]", write=self._set_autozero, query=lambda args: on_off(self.autozero))
        add(":ROUTe:TERMinals", write=lambda args: setattr(self, "terminals", parse_choice(args, ("FRONt", "REAR"))),
            query=lambda args: self.terminals[:4])
        add(":FORMat:ELEMents[:SENSe[1]]", write=self._set_elements,
            query=lambda args: ",".join(e[:4].upper() for e in ELEMENTS if e.upper() in self.elements))
        add(":OUTPut[1][:STATe]", write=self._set_output, query=lambda args: on_off(self.output_on))
        add(":READ", query=self._read)
        add(":MEASure", query=self._measure_present_functions)
        add(":CONFigure", query=lambda args: ",".join(FUNCTION_REPLY[f] for f in self.sense_functions))
        for function in FUNCTIONS:
            add(f":MEASure:{function}[:DC]", query=lambda args, f=function.upper(): self._measure(f, args))
            add(f":CONFigure:{function}[:DC]", write=lambda args, f=function.upper(): self._configure(f, args))
        add(":ABORt", write=lambda args: None)      # operation is always back in idle here

    def reset(self) -> None:
        """``*RST`` defaults (the manual's SCPI tables, section 18)."""
        self.output_on = False
        self.source_function = "VOLTAGE"
        self.current_setpoint_a = 0.0
        self.voltage_setpoint_v = 0.0
        self.current_range_a = _lowest_range(CURRENT_RANGES_A, DEFAULT_CURRENT_RANGE_A)
        self.voltage_source_range_v = _lowest_range(VOLTAGE_RANGES_V, DEFAULT_VOLTAGE_RANGE_V)
        self.current_source_autorange = True
        self.voltage_source_autorange = True
        self.source_delay_s = 0.0
        self.source_delay_auto = True
        self.auto_output_off = False
        self.sense_functions: tuple[str, ...] = ("CURRENT",)
        self.concurrent = True
        self._default_function_controls("VOLTAGE")
        self._default_function_controls("CURRENT")
        self.nplc = 1.0
        self.four_wire = False
        self.autozero = True
        self.terminals = "FRONT"
        self.elements = tuple(e.upper() for e in ELEMENTS)
        self.apply_to_heater()

    def _default_function_controls(self, function: str) -> None:
        """The ``*RST`` range, autorange and protection of one measure function."""
        if function == "VOLTAGE":
            self.compliance_v = DEFAULT_VOLTAGE_PROTECTION_V
            self.voltage_range_v = _lowest_range(VOLTAGE_RANGES_V, DEFAULT_VOLTAGE_RANGE_V)
            self.voltage_autorange = True
        else:
            self.current_compliance_a = DEFAULT_CURRENT_PROTECTION_A
            self.current_sense_range_a = _lowest_range(CURRENT_RANGES_A, DEFAULT_CURRENT_RANGE_A)
            self.current_autorange = True

    # -- commands ------------------------------------------------------------------
    def _add_boolean(self, pattern: str, attribute: str) -> None:
        write, query = boolean_setting(self, attribute)
        self.commands.add(pattern, write=write, query=query)

    def _add_number(self, pattern: str, attribute: str, low: float, high: float, default: float,
                    after=None) -> None:
        def write(args: list[str]) -> None:
            setattr(self, attribute, parse_number(args, low, high, default=default))
            if after is not None:
                after()
        self.commands.add(pattern, write=write, query=lambda args: f"{getattr(self, attribute):.6E}")

    def _register_source_commands(self) -> None:
        add = self.commands.add
        add(":SOURce[1]:FUNCtion[:MODE]", write=self._set_source_function,
            query=lambda args: self.source_function[:4])
        for function, limit, ranges, level, source_range, autorange in (
                ("CURRent", 1.05, CURRENT_RANGES_A, "current_setpoint_a", "current_range_a",
                 "current_source_autorange"),
                ("VOLTage", 210.0, VOLTAGE_RANGES_V, "voltage_setpoint_v", "voltage_source_range_v",
                 "voltage_source_autorange")):
            node = f":SOURce[1]:{function}"
            add(node + ":MODE", write=lambda args: parse_choice(args, ("FIXed",)), query=lambda args: "FIX")
            self._add_range(node, source_range, autorange, ranges, limit)
            self._add_number(node + "[:LEVel][:IMMediate][:AMPLitude]", level, -limit, limit, 0.0,
                             after=self.apply_to_heater)
        self._add_number(":SOURce[1]:DELay", "source_delay_s", 0.0, MAXIMUM_SOURCE_DELAY_S, 0.0,
                         after=lambda: setattr(self, "source_delay_auto", False))
        self._add_boolean(":SOURce[1]:DELay:AUTO", "source_delay_auto")
        add(":SOURce[1]:CLEar[:IMMediate]", write=lambda args: self.turn_output(False))
        self._add_boolean(":SOURce[1]:CLEar:AUTO", "auto_output_off")

    def _register_sense_commands(self) -> None:
        add = self.commands.add
        add("[:SENSe[1]]:FUNCtion[:ON]", write=self._sense_functions_on, query=lambda args: ",".join(
            FUNCTION_REPLY[f] for f in self.sense_functions))
        add("[:SENSe[1]]:FUNCtion[:ON]:ALL", write=lambda args: setattr(self, "sense_functions",
                                                                         ("VOLTAGE", "CURRENT")))
        add("[:SENSe[1]]:FUNCtion:OFF", write=self._sense_functions_off)
        add("[:SENSe[1]]:FUNCtion:OFF:ALL", write=lambda args: setattr(self, "sense_functions", ()))
        self._add_boolean("[:SENSe[1]]:FUNCtion:CONCurrent", "concurrent")
        for function, limit, ranges, protection, default_protection, sense_range, autorange in (
                ("VOLTage", 210.0, VOLTAGE_RANGES_V, "compliance_v", DEFAULT_VOLTAGE_PROTECTION_V,
                 "voltage_range_v", "voltage_autorange"),
                ("CURRent", 1.05, CURRENT_RANGES_A, "current_compliance_a", DEFAULT_CURRENT_PROTECTION_A,
                 "current_sense_range_a", "current_autorange")):
            node = f"[:SENSe[1]]:{function}[:DC]"
            self._add_number(node + ":PROTection[:LEVel]", protection, -limit, limit, default_protection,
                             after=self._protection_set)
            # tripped: the output is limited by this function's protection
            limits_voltage = function == "VOLTage"
            add(node + ":PROTection:TRIPped", query=lambda args, v=limits_voltage: on_off(
                self.in_compliance and self.sourcing_voltage != v))
            self._add_range(node, sense_range, autorange, ranges, limit)
            self._add_number(node + ":NPLCycles", "nplc", 0.01, 10.0, 1.0)

    def _add_range(self, node: str, attribute: str, autorange: str, ranges: tuple[float, ...],
                   limit: float) -> None:
        """``<node>:RANGe[:UPPer]`` (the lowest range holding the value; autorange off) and ``:RANGe:AUTO``."""
        def write(args: list[str]) -> None:
            setattr(self, attribute, _lowest_range(ranges, parse_number(args, -limit, limit, default=ranges[-1])))
            setattr(self, autorange, False)
        self.commands.add(node + ":RANGe[:UPPer]", write=write,
                          query=lambda args: f"{getattr(self, attribute):.6E}")
        self._add_boolean(node + ":RANGe:AUTO", autorange)

    def _protection_set(self) -> None:
        self.compliance_v = abs(self.compliance_v)
        self.current_compliance_a = abs(self.current_compliance_a)
        self.apply_to_heater()

    def _set_source_function(self, args: list[str]) -> None:
        choice = parse_choice(args, ("CURRent", "VOLTage", "MEMory"))
        if choice == "MEMORY":
            raise scpi_error(ILLEGAL_PARAMETER_VALUE)     # source-memory sweeps are not simulated
        self.source_function = choice
        self.apply_to_heater()

    @staticmethod
    def _function_of(text: str) -> str:
        text = text.strip().strip("'\"").upper()
        for function in FUNCTIONS:
            long_form, short = function.upper(), short_form(function)
            if text in (long_form, short, long_form + ":DC", short + ":DC"):
                return long_form
        raise scpi_error(ILLEGAL_PARAMETER_VALUE)

    def _sense_functions_on(self, args: list[str]) -> None:
        if not args:
            raise scpi_error(ILLEGAL_PARAMETER_VALUE)
        chosen = [self._function_of(arg) for arg in args]
        if not self.concurrent:
            self.sense_functions = (chosen[-1],)
            return
        wanted = set(self.sense_functions) | set(chosen)
        self.sense_functions = tuple(f for f in ("VOLTAGE", "CURRENT") if f in wanted)

    def _sense_functions_off(self, args: list[str]) -> None:
        off = {self._function_of(arg) for arg in args}
        self.sense_functions = tuple(f for f in self.sense_functions if f not in off)

    def _set_autozero(self, args: list[str]) -> None:
        if single_argument(args).strip().upper() == "ONCE":
            return                                 # a single zero now: nothing to simulate
        self.autozero = parse_boolean(args)

    def _set_elements(self, args: list[str]) -> None:
        chosen = {parse_choice([arg], ELEMENTS) for arg in args}
        self.elements = tuple(e.upper() for e in ELEMENTS if e.upper() in chosen)

    def _set_output(self, args: list[str]) -> None:
        if not self.turn_output(parse_boolean(args)):
            raise ScpiError(*OUTPUT_BLOCKED)

    # -- the output --------------------------------------------------------------------
    @property
    def sourcing_voltage(self) -> bool:
        return self.source_function == "VOLTAGE"

    @property
    def in_compliance(self) -> bool:
        """Current-limited (sourcing voltage) or voltage-limited (sourcing current)."""
        if not self.sourcing_voltage:
            return super().in_compliance
        return self.output_on and abs(self.voltage_setpoint_v) / self.load_resistance_ohm > self.current_compliance_a

    @property
    def output_voltage_v(self) -> float:
        if not self.sourcing_voltage:
            return super().output_voltage_v
        if not self.output_on:
            return 0.0
        if self.in_compliance:
            return math.copysign(self.current_compliance_a * self.load_resistance_ohm, self.voltage_setpoint_v)
        return self.voltage_setpoint_v

    @property
    def output_current_a(self) -> float:
        if not self.sourcing_voltage:
            return super().output_current_a
        if not self.output_on:
            return 0.0
        if self.in_compliance:
            return math.copysign(self.current_compliance_a, self.voltage_setpoint_v)
        return self.voltage_setpoint_v / self.load_resistance_ohm

    @property
    def measurement_condition(self) -> int:
        """Measurement condition register: B11 output enable asserted, B14 compliance."""
        value = 0 if self.output_blocked else OUTPUT_ENABLE_ASSERTED_BIT
        return value | (COMPLIANCE_BIT if self.in_compliance else 0)

    # -- readings ------------------------------------------------------------------------
    def _configure(self, function: str, args: list[str]) -> None:
        """``:CONFigure:<function>``: that function alone, its controls at ``*RST``, output on."""
        if args:
            raise scpi_error(ILLEGAL_PARAMETER_VALUE)
        self.sense_functions = (function,)
        self._default_function_controls(function)
        self._set_output(["ON"])

    def _measure(self, function: str, args: list[str]) -> str:
        """``:MEASure:<function>?``: ``:CONFigure:<function>`` then ``:READ?``."""
        self._configure(function, args)
        return self._read([])

    def _measure_present_functions(self, args: list[str]) -> str:
        """``:MEASure?`` without a function: the functions selected now, output on, one reading."""
        if args:
            raise scpi_error(ILLEGAL_PARAMETER_VALUE)
        self._set_output(["ON"])
        return self._read([])

    def _read(self, args: list[str]) -> str:
        if not self.output_on and not self.auto_output_off:
            raise ScpiError(*NOT_WITH_OUTPUT_OFF)
        switched_on = not self.output_on
        if switched_on:
            self._set_output(["ON"])
        reading = self._format_reading()
        if switched_on:
            self.turn_output(False)
        return reading

    def _format_reading(self) -> str:
        measured = self.sense_functions
        voltage = (self.output_voltage_v if "VOLTAGE" in measured
                   else self.voltage_setpoint_v if self.sourcing_voltage else NOT_A_NUMBER)
        current = (self.output_current_a if "CURRENT" in measured
                   else self.current_setpoint_a if not self.sourcing_voltage else NOT_A_NUMBER)
        values = {"VOLTAGE": voltage, "CURRENT": current, "RESISTANCE": NOT_A_NUMBER, "TIME": self.clock.now(),
                  "STATUS": float(self._status_word())}
        return ",".join(f"{values[element]:+.6E}" for element in self.elements)

    def _status_word(self) -> int:
        word = STATUS_SOURCING_VOLTAGE if self.sourcing_voltage else STATUS_SOURCING_CURRENT
        if self.terminals == "FRONT":
            word |= STATUS_FRONT_TERMINALS
        if self.in_compliance:
            word |= STATUS_COMPLIANCE
        if "VOLTAGE" in self.sense_functions:
            word |= STATUS_VOLTAGE_MEASURED
        if "CURRENT" in self.sense_functions:
            word |= STATUS_CURRENT_MEASURED
        if self.four_wire:
            word |= STATUS_REMOTE_SENSE
        return word
