"""A third-party client checks the simulated instruments: PyMeasure's own Keithley classes over TCP.

PyMeasure's ``Keithley6221``, ``Keithley2400`` and ``Keithley2000`` (the
closest PyMeasure has to the 2002) are written from the manuals by other
people and used on real instruments. Here they drive the simulated 6221,
2400 and 2002 through pyvisa-py on ``TCPIP0::127.0.0.1::<port>::SOCKET``,
exactly as a lab script would drive the real ones, and the tests check what
the instrument did (heater power in the simulated cryostat, read-backs,
error queue, status registers), not only that no exception was raised.
"""

import types

import pytest
from pymeasure.instruments.keithley import Keithley2000, Keithley2400, Keithley6221
from pymeasure.instruments.keithley import keithley2400 as pymeasure_keithley2400
from pyvisa.errors import VisaIOError

from drivers.clock import MonotonicClock
from simulated_hw.bench import SimulatedBench
from simulated_hw.scpi_server import ScpiServer

HEATER_RESISTANCE_OHM = 50.0
TIMEOUT_MS = 2000
#: Bits of *ESR? (IEEE 488.2): operation complete, device-dependent, execution, command error, power on.
OPC, DDE, EXE, CME, PON = 1, 8, 16, 32, 128
#: Bits of *STB?: error available, event summary, master summary.
EAV, ESB, MSS = 4, 32, 64
UNDEFINED_HEADER = [-113.0, '"Undefined header"']


@pytest.fixture
def served(flange_curve, ptc_stage_curve):
    """``served(pymeasure_class, role, supply)``: (bench, client) on a fresh simulated bench over TCP."""
    opened = []

    def serve(pymeasure_class, role="heater_supply", supply="6221"):
        bench = SimulatedBench(MonotonicClock(), flange_curve, ptc_stage_curve, supply=supply, noise=False,
                               heater_resistance_ohm=HEATER_RESISTANCE_OHM)
        server = ScpiServer(getattr(bench, role)).start()
        client = pymeasure_class(server.resource_name, visa_library="@py", read_termination="\n",
                                 write_termination="\n", timeout=TIMEOUT_MS)
        opened.append((server, client))
        return bench, client

    yield serve
    for server, client in opened:
        client.adapter.close()
        server.stop()


def heater_power_w(bench, client) -> float:
    """The simulated heater's power once the instrument has executed what was written.

    A write returns when the bytes are sent; ``*OPC?`` (PyMeasure's ``complete``) answers
    after every command before it has run.
    """
    assert client.complete == "1"
    return bench.cryostat.heater_power_w


def event_status(client) -> int:
    """``*ESR?`` (PyMeasure's 2400 and 2000 classes have no property for it)."""
    return int(client.ask("*ESR?"))


def source_current_after_reset(meter, current_a, compliance_v, *, measure_voltage=False):
    """Through PyMeasure's 2400 API: reset, source ``current_a`` with ``compliance_v``."""
    meter.reset()
    meter.source_mode = "current"
    meter.source_current = current_a
    meter.compliance_voltage = compliance_v
    if measure_voltage:
        meter.write(":SENSe:FUNCtion 'VOLTage'")  # concurrent with the current of *RST


@pytest.fixture
def no_ramp_pauses(monkeypatch):
    """PyMeasure's 2400 ramps pause 20 ms per step with ``time.sleep``: count the pauses instead."""
    pauses = []
    monkeypatch.setattr(pymeasure_keithley2400, "time", types.SimpleNamespace(sleep=pauses.append))
    return pauses


# ---------------------------------------------------------------------------
# Keithley 6221
# ---------------------------------------------------------------------------
def test_6221_identity_and_power_on_event(served):
    bench, source = served(Keithley6221)
    assert source.id.startswith("KEITHLEY INSTRUMENTS INC.,MODEL 6221,")
    assert source.standard_events == PON          # first *ESR? after switching on
    assert source.standard_events == 0            # reading cleared it
    assert int(source.status) == 0
    assert source.complete == "1"
    assert source.check_errors() == []


def test_6221_reset_reaches_rst_and_turns_the_output_off(served):
    bench, source = served(Keithley6221)
    source.source_current = 0.02
    source.source_compliance = 5
    source.output_low_grounded = True
    source.source_delay = 0.5
    source.enable_source()
    assert heater_power_w(bench, source) == pytest.approx(0.02 ** 2 * HEATER_RESISTANCE_OHM)
    source.write(":SOURce:WOBBle 1")              # an error left in the queue
    # "status:queue:clear;*RST;:stat:pres;:*CLS;": every unit of it must run
    source.reset()
    assert source.source_enabled is False
    assert source.source_current == 0.0
    assert heater_power_w(bench, source) == 0.0
    assert source.source_compliance == 10.0       # *RST values
    assert source.output_low_grounded is False
    assert source.source_delay == pytest.approx(1e-3)
    assert source.check_errors() == []
    assert source.standard_events == 0            # *CLS cleared the command-error bit


def test_6221_source_current_compliance_and_output(served):
    bench, source = served(Keithley6221)
    source.reset()
    source.source_current = 0.04
    source.source_compliance = 5
    source.source_range = 0.1
    assert (source.source_current, source.source_compliance, source.source_range) == (0.04, 5.0, 0.1)
    assert source.source_auto_range is False
    assert source.source_enabled is False and heater_power_w(bench, source) == 0.0
    source.enable_source()
    assert source.source_enabled is True
    assert heater_power_w(bench, source) == pytest.approx(0.04 ** 2 * HEATER_RESISTANCE_OHM)
    assert source.measurement_events & 8 == 0     # B3 compliance: not latched
    source.source_current = 0.105                 # 5.25 V needed, 5 V allowed
    assert heater_power_w(bench, source) == pytest.approx(5.0 ** 2 / HEATER_RESISTANCE_OHM)
    assert source.measurement_events & 8 == 8     # compliance latched in the event register
    source.disable_source()
    assert source.source_enabled is False and heater_power_w(bench, source) == 0.0
    assert source.check_errors() == []


def test_6221_errors_and_event_status(served):
    bench, source = served(Keithley6221)
    source.reset()
    source.srq_event_enabled = ESB
    source.write("*ESE 60")                       # PyMeasure's standard_event_enabled forgets the '*'
    source.write(":OUTPut:LOWEarth 1")
    assert int(source.status) == EAV | ESB | MSS
    assert source.check_errors() == [UNDEFINED_HEADER]
    assert source.standard_events == CME
    source.write(":SOURce:CURRent 1")             # 1 A: outside -105 mA to 105 mA
    assert source.next_error == [-222.0, '"Parameter data out of range"']
    assert source.source_current == 0.0
    assert source.standard_events == EXE
    source.write("*OPC")
    assert source.standard_events == OPC
    assert source.srq_event_enabled == ESB


def test_6221_a_query_pymeasure_misspells_gets_no_reply_and_an_error(served):
    bench, source = served(Keithley6221)
    source.adapter.connection.timeout = 200
    with pytest.raises(VisaIOError):
        source.standard_event_enabled             # sends "ESE?", no header a 6221 knows
    assert source.check_errors() == [UNDEFINED_HEADER]


def test_6221_shutdown_leaves_the_output_off(served):
    bench, source = served(Keithley6221)
    source.source_current = 0.05
    source.enable_source()
    assert heater_power_w(bench, source) > 0.1
    source.shutdown()
    assert source.source_enabled is False
    assert bench.heater_supply.output_on is False and heater_power_w(bench, source) == 0.0


# ---------------------------------------------------------------------------
# Keithley 2400
# ---------------------------------------------------------------------------
def test_2400_identity_reset_and_clean_error_queue(served):
    bench, meter = served(Keithley2400, supply="2400")  # the constructor sets :FORMAT:ELEMENTS
    assert meter.id.startswith("KEITHLEY INSTRUMENTS INC.,MODEL 2400,")
    meter.source_mode = "current"
    meter.source_current = 0.03
    meter.enable_source()
    assert heater_power_w(bench, meter) == pytest.approx(0.03 ** 2 * HEATER_RESISTANCE_OHM)
    meter.reset()
    assert meter.source_enabled is False and heater_power_w(bench, meter) == 0.0
    assert meter.source_mode == "voltage"          # the 2400's *RST source function
    assert meter.source_current == 0.0
    assert meter.check_errors() == []


def test_2400_sources_current_and_measures(served):
    bench, meter = served(Keithley2400, supply="2400")
    source_current_after_reset(meter, 0.02, 5)
    meter.source_current_range = 0.1
    meter.voltage_range_auto_enabled = False
    assert (meter.source_current, meter.compliance_voltage) == (0.02, 5.0)
    assert meter.voltage_range_auto_enabled is False
    meter.enable_source()
    assert meter.source_enabled is True
    assert heater_power_w(bench, meter) == pytest.approx(0.02 ** 2 * HEATER_RESISTANCE_OHM)
    voltage, current, resistance, time_s, status = meter.values(":READ?")
    assert voltage == 9.91e37                     # after *RST only the current is measured
    assert current == pytest.approx(0.02)
    meter.write(":SENSe:FUNCtion 'VOLTage'")      # concurrent with the current
    voltage, current, resistance, time_s, status = meter.values(":READ?")
    assert (voltage, current, resistance) == (pytest.approx(1.0), pytest.approx(0.02), 9.91e37)
    assert int(status) & (1 << 15) and not int(status) & (1 << 3)   # sourcing current, not in compliance
    assert meter.voltage == pytest.approx(1.0)    # :MEASURE:VOLTAGE?
    assert meter.current == pytest.approx(0.02)   # :MEASURE:CURRENT?
    # :MEASure is :CONFigure then :READ?, and :CONFigure returns the function's controls,
    # the voltage protection among them, to their *RST values
    assert meter.compliance_voltage == 21.0
    assert meter.check_errors() == []


def test_2400_compliance(served):
    bench, meter = served(Keithley2400, supply="2400")
    source_current_after_reset(meter, 0.2, 5, measure_voltage=True)   # 10 V needed
    meter.enable_source()
    voltage, current, _, _, status = meter.values(":READ?")
    assert voltage == pytest.approx(5.0)          # the compliance limit
    assert current == pytest.approx(5.0 / HEATER_RESISTANCE_OHM)   # measured: what flows
    assert int(status) & (1 << 3)                 # status word: in compliance
    assert meter.ask(":SENSe:VOLTage:PROTection:TRIPped?").strip() == "1"
    assert heater_power_w(bench, meter) == pytest.approx(5.0 ** 2 / HEATER_RESISTANCE_OHM)


def test_2400_sources_voltage_with_current_compliance(served):
    bench, meter = served(Keithley2400, supply="2400")
    meter.reset()
    meter.source_voltage = 1.0
    meter.compliance_current = 0.1
    meter.enable_source()
    assert heater_power_w(bench, meter) == pytest.approx(1.0 ** 2 / HEATER_RESISTANCE_OHM)
    voltage, current, *_ = meter.values(":READ?")
    assert voltage == pytest.approx(1.0) and current == pytest.approx(0.02)
    # :MEASURE:CURRENT? puts the current protection back at its *RST 105 uA: now in compliance
    assert meter.current == pytest.approx(105e-6)
    assert meter.compliance_current == pytest.approx(105e-6)
    assert heater_power_w(bench, meter) == pytest.approx((105e-6) ** 2 * HEATER_RESISTANCE_OHM)


def test_2400_errors_and_event_status(served):
    bench, meter = served(Keithley2400, supply="2400")
    meter.reset()                                 # "*RST": the event register keeps power-on
    assert event_status(meter) == PON
    meter.write(":SOURce:CURRent:WOBBle 1")
    assert meter.check_errors() == [UNDEFINED_HEADER]
    assert event_status(meter) == CME
    meter.write(":READ?")                         # output off: +803 and no reply
    assert meter.check_errors() == [[803.0, '"Not permitted with OUTPUT off"']]
    assert event_status(meter) == DDE
    bench.heater_supply.inject_refuse_output()
    meter.source_enabled = True
    assert meter.check_errors() == [[802.0, '"OUTPUT blocked by output enable"']]
    assert meter.source_enabled is False


def test_2400_shutdown_ramps_to_zero_and_turns_the_output_off(served, no_ramp_pauses):
    bench, meter = served(Keithley2400, supply="2400")
    source_current_after_reset(meter, 0.05, 21)
    meter.enable_source()
    assert heater_power_w(bench, meter) == pytest.approx(0.05 ** 2 * HEATER_RESISTANCE_OHM)
    meter.shutdown()                              # ramp_to_current(0), :ABOR, OUTPUT 0
    assert len(no_ramp_pauses) == 30
    assert meter.source_current == 0.0
    assert meter.source_enabled is False and heater_power_w(bench, meter) == 0.0
    assert meter.check_errors() == []


def test_2400_shutdown_after_reset_ramps_the_voltage_source(served, no_ramp_pauses):
    bench, meter = served(Keithley2400, supply="2400")
    meter.reset()
    meter.shutdown()                              # source function VOLT after *RST
    assert meter.source_voltage == 0.0 and meter.source_enabled is False
    assert meter.check_errors() == []


# ---------------------------------------------------------------------------
# Keithley 2002, through PyMeasure's Keithley2000 (PyMeasure has no 2002 class)
# ---------------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore:It is not known whether this device support SCPI")
def test_2002_through_pymeasure_keithley2000(served):
    bench, dmm = served(Keithley2000, role="flange_dmm")
    assert dmm.id.startswith("KEITHLEY INSTRUMENTS INC.,MODEL 2002,")
    dmm.resistance_4W_nplc = 2
    dmm.resistance_4W_range = 2e3                 # ":SENS:FRES:RANG:AUTO 0;:SENS:FRES:RANG 2000"
    dmm.resistance_4W_digits = 7
    assert (dmm.resistance_4W_nplc, dmm.resistance_4W_range, dmm.resistance_4W_digits) == (2, 2000, 7)
    assert dmm.check_errors() == []
    dmm.write(":SENSe:FRESistance:WOBBle 1")
    dmm.reset()                                   # ":STAT:QUEUE:CLEAR;*RST;:STAT:PRES;:*CLS;"
    assert dmm.resistance_4W_nplc == 1 and dmm.resistance_4W_range == 2e6
    assert dmm.check_errors() == []
    assert event_status(dmm) == 0
