"""Keithley 2400 SourceMeter as the flange heater supply: source current, measure voltage.

Commands from the 2400 Series SourceMeter User's Manual (2400S-900-01),
section 18 "SCPI Command Reference"; every string sent is listed in
``docs/explanation/instruments.md``. The 2400 sources the heater current with a voltage
compliance (``:SENSe:VOLTage:PROTection``) and measures the voltage it takes,
so the delivered heater power V I is known, not assumed
(``voltage_measured=True``). ``:SENSe:VOLTage:PROTection:TRIPped?`` tells
whether the output is in compliance. An output blocked by the output-enable
line is reported by the 2400 as ``+802,"OUTPUT blocked by output enable"``.

Examples
--------
>>> from drivers.clock import VirtualClock
>>> from simulated_hw.bench import SimulatedBench
>>> clock = VirtualClock()
>>> bench = SimulatedBench(clock, supply="2400", heater_resistance_ohm=50.0)
>>> heater = Keithley2400(bench.in_process_transports().heater_supply, clock, heater_resistance_ohm=50.0)
>>> _ = heater.set_power_w(0.05)
>>> readback = heater.read_back()
>>> round(readback.voltage_v, 4), round(readback.power_w, 6), readback.voltage_measured
(1.5811, 0.05, True)
>>> heater.close()
"""

from __future__ import annotations

from drivers.clock import Clock
from drivers.errors import BadReply, HeaterRefused
from drivers.heater import HeaterReadback, HeaterSupply
from drivers.scpi import Control, number, on_off, one_of, parse_bool, parse_token
from drivers.transports.base import Transport


class Keithley2400(HeaterSupply):
    """Driver of a Keithley 2400 sourcing the heater current (see :class:`drivers.heater.HeaterSupply`).

    Parameters beyond those of :class:`~drivers.heater.HeaterSupply`:

    four_wire : bool
        Remote sense (``:SYSTem:RSENse ON``): the voltage is measured at the heater, not at
        the terminals, so lead resistance does not count as heater power.
    nplc : float
        Integration time of the voltage measurement (power-line cycles).
    """

    expected_model = "MODEL 2400"
    supply_max_current_a = 1.05
    supply_compliance_range_v = (0.0, 210.0)

    source_function = Control(":SOURce:FUNCtion {}", ":SOURce:FUNCtion?", "Source function (18, SOURce).",
                              one_of({"current": "CURRent"}), parse_token({"current": "CURRent"}))
    source_mode = Control(":SOURce:CURRent:MODE {}", ":SOURce:CURRent:MODE?", "Current source mode.",
                          one_of({"fixed": "FIXed"}), parse_token({"fixed": "FIXed"}))
    source_range_a = Control(":SOURce:CURRent:RANGe {}", ":SOURce:CURRent:RANGe?",
                             "Source range in A (lowest range holding the value, 1 uA to 1 A).",
                             number(0.0, 1.05, "A", "{:.6E}"), float)
    source_current_a = Control(":SOURce:CURRent {}", ":SOURce:CURRent?",
                               "Output current in A, -1.05 to 1.05 (:SOURce:CURRent[:LEVel][:IMMediate]).",
                               number(-1.05, 1.05, "A", "{:.6E}"), float)
    sense_function = Control(":SENSe:FUNCtion {}", ":SENSe:FUNCtion?", "Measured function (18, SENSe1).",
                             one_of({"voltage": '"VOLTage"'}), parse_token({"voltage": "VOLTage:DC"}))
    compliance_v = Control(":SENSe:VOLTage:PROTection {}", ":SENSe:VOLTage:PROTection?",
                           "Voltage compliance in V (:SENSe:VOLTage:PROTection[:LEVel]).",
                           number(0.0, 210.0, "V", "{:.6E}"), float)
    voltage_range_v = Control(":SENSe:VOLTage:RANGe {}", ":SENSe:VOLTage:RANGe?",
                              "Voltage measurement range in V (holds the compliance).",
                              number(0.0, 210.0, "V", "{:.6E}"), float)
    nplc = Control(":SENSe:VOLTage:NPLCycles {}", ":SENSe:VOLTage:NPLCycles?",
                   "Voltage integration time, 0.01 to 10 PLC.", number(0.01, 10.0, "PLC"), float)
    remote_sense = Control(":SYSTem:RSENse {}", ":SYSTem:RSENse?", "4-wire remote sense on/off.",
                           on_off, parse_bool)
    data_elements = Control(":FORMat:ELEMents {}", ":FORMat:ELEMents?",
                            "Elements of a :READ? reply (:FORMat:ELEMents[:SENSe[1]]).",
                            one_of({("voltage", "current"): "VOLTage,CURRent"}), str)

    def __init__(self, transport: Transport, clock: Clock, heater_resistance_ohm: float, *,
                 max_current_a: float = 0.1, voltage_compliance_v: float = 10.0, name: str = "heater supply",
                 check_identity: bool = True, verify_each_setting: bool = True, four_wire: bool = False,
                 nplc: float = 1.0):
        self.four_wire = four_wire
        self.voltage_nplc = nplc
        super().__init__(transport, clock, heater_resistance_ohm, max_current_a=max_current_a,
                         voltage_compliance_v=voltage_compliance_v, name=name, check_identity=check_identity,
                         verify_each_setting=verify_each_setting)

    def configure_source(self) -> None:
        self.write("*CLS")
        self.output_enabled = False
        self.source_function = "current"
        self.source_mode = "fixed"
        self.source_range_a = self.max_current_a
        self.source_current_a = 0.0
        self.sense_function = "voltage"
        self.compliance_v = self.voltage_compliance_v
        self.voltage_range_v = self.voltage_compliance_v
        self.nplc = self.voltage_nplc
        self.remote_sense = self.four_wire
        self.data_elements = ("voltage", "current")
        self.check_error_queue("source-meter configuration")

    def output_refused(self) -> HeaterRefused:
        return HeaterRefused(self.label, "output refused (output enable or interlock)",
                             error_queue=self.read_error_queue())

    compliance_query = ":SENSe:VOLTage:PROTection:TRIPped?"

    def compliance_from_reply(self, reply: str) -> bool:
        try:
            return parse_bool(reply)
        except ValueError:
            raise BadReply(self.label, f"compliance state: reply to {self.compliance_query} is not 1 or 0",
                           reply=reply) from None

    def measure_output(self) -> HeaterReadback:
        if not self.output_is_on:
            return HeaterReadback(0.0, 0.0, 0.0, voltage_measured=True)
        reply = self.query(":READ?")
        fields = reply.split(",")
        try:
            voltage, current = (float(field) for field in fields)
        except ValueError:
            raise BadReply(self.label, "expected <voltage>,<current> from :READ?", reply=reply) from None
        self.check_compliance()
        return HeaterReadback(current, voltage, voltage * current, voltage_measured=True)
