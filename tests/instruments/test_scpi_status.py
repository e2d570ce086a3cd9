"""IEEE 488.2 common commands, the status model and errors inside a program message, in process.

Each simulated instrument is driven with raw program messages through
``handle`` (what the TCP server calls for each line). Bits: *ESR? B0 OPC,
B3 DDE, B4 EXE, B5 CME, B7 PON; *STB? B0 MSB, B2 EAV, B4 MAV, B5 ESB, B6 MSS.
"""

import pytest

from simulated_hw.bench import SimulatedBench

OPC, DDE, EXE, CME, PON = 1, 8, 16, 32, 128
MSB, EAV, MAV, ESB, MSS = 1, 4, 16, 32, 64
IDN_START = "KEITHLEY INSTRUMENTS INC.,MODEL "


@pytest.fixture(params=["2002", "6221", "2400"])
def instrument(request, clock, flange_curve, ptc_stage_curve):
    """Each simulated instrument, its power-on event already read."""
    supply = request.param if request.param != "2002" else "6221"
    bench = SimulatedBench(clock, flange_curve, ptc_stage_curve, supply=supply, noise=False)
    device = bench.flange_dmm if request.param == "2002" else bench.heater_supply
    assert device.handle("*ESR?") == str(PON)
    return device


@pytest.fixture
def supply_6221(bench):
    bench.heater_supply.handle("*CLS")
    return bench.heater_supply


@pytest.fixture
def supply_2400(clock, flange_curve, ptc_stage_curve):
    bench = SimulatedBench(clock, flange_curve, ptc_stage_curve, supply="2400", noise=False)
    bench.heater_supply.handle("*CLS")
    return bench.heater_supply


def errors(device) -> list[str]:
    """Read the error queue to its end, as ``:SYSTem:ERRor?`` does."""
    entries = []
    while (entry := device.handle(":SYSTem:ERRor?")) != '0,"No error"':
        entries.append(entry)
    return entries


# ---------------------------------------------------------------------------
# errors inside a program message (the manuals' command execution rules)
# ---------------------------------------------------------------------------
def test_units_before_an_unknown_header_run_and_those_after_it_do_not(instrument):
    reply = instrument.handle("*IDN?;:SYSTem:WOBBle;*IDN?;*ESE 4")
    assert reply.startswith(IDN_START) and ";" not in reply      # one reply: the first query only
    assert instrument.handle("*ESE?") == "0"                       # *ESE 4 came after the error
    assert errors(instrument) == ['-113,"Undefined header"']
    assert instrument.handle("*ESR?") == str(CME)


def test_a_message_starting_with_an_unknown_header_is_ignored_whole(supply_6221):
    assert supply_6221.handle(":SOURce:CURRent 0.01;:OUTPut ON") is None
    assert supply_6221.output_on
    assert supply_6221.handle(":OUTPut:WOBBle;:OUTPut OFF") is None
    assert supply_6221.output_on                                    # OFF never ran
    assert errors(supply_6221) == ['-113,"Undefined header"']


def test_an_execution_error_ends_the_message_too(supply_6221):
    assert supply_6221.handle(":SOURce:CURRent 1;:OUTPut ON;:OUTPut?") is None
    assert not supply_6221.output_on and supply_6221.current_setpoint_a == 0.0
    assert errors(supply_6221) == ['-222,"Parameter data out of range"']
    assert supply_6221.handle("*ESR?") == str(EXE)


def test_pymeasure_reset_message_runs_every_unit(supply_6221):
    supply_6221.handle(":SOURce:CURRent 0.01;:OUTPut ON;:OUTPut:WOBBle")
    assert supply_6221.handle("status:queue:clear;*RST;:stat:pres;:*CLS;") is None
    assert not supply_6221.output_on and supply_6221.current_setpoint_a == 0.0
    assert errors(supply_6221) == [] and supply_6221.handle("*ESR?") == "0"


def test_a_common_command_with_a_parameter_it_does_not_take(instrument):
    assert instrument.handle("*CLS 1") is None
    assert errors(instrument) == ['-108,"Parameter not allowed"']


# ---------------------------------------------------------------------------
# common commands
# ---------------------------------------------------------------------------
def test_event_status_register_bits_by_error_class(supply_2400):
    supply_2400.handle(":SYSTem:WOBBle")                            # -113: command error
    supply_2400.handle(":SOURce:CURRent 2")                         # -222: execution error
    supply_2400.handle(":READ?")                                    # +803: device-dependent error
    supply_2400.handle("*OPC")
    assert supply_2400.handle("*ESR?") == str(CME | EXE | DDE | OPC)
    assert supply_2400.handle("*ESR?") == "0"                       # read and cleared
    assert errors(supply_2400) == ['-113,"Undefined header"', '-222,"Parameter data out of range"',
                                   '803,"Not permitted with OUTPUT off"']


def test_a_full_error_queue_sets_the_device_dependent_bit(instrument):
    instrument.handle("*CLS")
    for _ in range(11):
        instrument.handle(":SYSTem:WOBBle")
    assert instrument.handle("*ESR?") == str(CME | DDE)
    queue = errors(instrument)
    assert len(queue) == 10 and queue[-1] == '-350,"Queue overflow"'


def test_enable_registers_and_status_byte(instrument):
    assert instrument.handle("*STB?") == "0"
    assert instrument.handle("*ESE 36;*SRE 255;*ESE?;*SRE?") == "36;191"    # SRE bit 6 reads 0
    instrument.handle(":SYSTem:WOBBle")
    assert instrument.handle("*STB?") == str(EAV | ESB | MSS)
    assert instrument.handle("*IDN?;*STB?").endswith(f";{EAV | MAV | ESB | MSS}")   # a reply is waiting
    instrument.handle(":SYSTem:ERRor?")
    assert instrument.handle("*STB?") == str(ESB | MSS)            # queue read: EAV off; ESR not read yet
    assert instrument.handle("*ESR?;*STB?") == f"{CME};{MAV | MSS}"
    assert instrument.handle("*ESE 256") is None
    assert errors(instrument) == ['-222,"Parameter data out of range"']


def test_cls_clears_events_and_errors_but_not_enables(instrument):
    instrument.handle("*ESE 32;*SRE 32;:SYSTem:WOBBle")
    instrument.handle("*CLS")
    assert instrument.handle("*ESR?;*STB?;*ESE?;*SRE?") == "0;16;32;32"
    assert errors(instrument) == []


def test_rst_keeps_the_status_model(instrument):
    instrument.handle("*ESE 32;*SRE 32;:STATus:OPERation:ENABle 1024;:SYSTem:WOBBle")
    instrument.handle("*RST")
    assert instrument.handle("*ESE?;*SRE?;:STATus:OPERation:ENABle?") == "32;32;1024"
    assert instrument.handle("*ESR?") == str(CME)
    assert errors(instrument) == ['-113,"Undefined header"']


def test_opc_tst_wai(instrument):
    assert instrument.handle("*OPC?") == "1"
    assert instrument.handle("*ESR?") == "0"                       # *OPC? does not set the bit
    assert instrument.handle("*OPC;*WAI;*TST?") == "0"
    assert instrument.handle("*ESR?") == str(OPC)


def test_queue_clear_commands(instrument):
    for clear in (":STATus:QUEue:CLEar", ":SYSTem:CLEar", "*CLS"):
        instrument.handle(":SYSTem:WOBBle;")
        assert instrument.handle(":STATus:QUEue?") == '-113,"Undefined header"'
        instrument.handle(":SYSTem:WOBBle;")
        instrument.handle(clear)
        assert instrument.handle(":STATus:QUEue:NEXT?") == '0,"No error"'


# ---------------------------------------------------------------------------
# SCPI register sets
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("supply_name, compliance_bit, setup", [
    ("supply_6221", 1 << 3, ""),
    ("supply_2400", 1 << 14, ":SOURce:FUNCtion CURRent;"),        # the 2400's *RST sources voltage
])
def test_measurement_register_set_latches_compliance(request, supply_name, compliance_bit, setup):
    supply = request.getfixturevalue(supply_name)
    supply.handle(setup + ":SOURce:CURRent 0.1;:OUTPut ON")       # 50 ohm: 5 V, under compliance
    assert int(supply.handle(":STATus:MEASurement:CONDition?")) & compliance_bit == 0
    supply.handle(f":STATus:MEASurement:ENABle {compliance_bit};*SRE 1")
    supply.inject_open_heater()
    assert int(supply.handle(":STATus:MEASurement:CONDition?")) & compliance_bit
    supply.inject_open_heater(False)
    assert int(supply.handle(":STATus:MEASurement:CONDition?")) & compliance_bit == 0
    assert supply.handle("*STB?") == str(MSB | MSS)                # the event stayed latched
    assert int(supply.handle(":STATus:MEASurement?")) & compliance_bit
    assert int(supply.handle(":STATus:MEASurement:EVENt?")) & compliance_bit == 0    # read cleared it
    assert supply.handle(":STATus:MEASurement:ENABle?") == str(compliance_bit)
    supply.handle(":STATus:PRESet")
    assert supply.handle(":STATus:MEASurement:ENABle?;*SRE?") == "0;1"   # SRE is not a SCPI register
    assert errors(supply) == []


def test_register_enable_range(instrument):
    assert instrument.handle(":STATus:QUEStionable:ENABle 65535;:STATus:QUEStionable:ENABle?") == "32767"
    instrument.handle(":STATus:QUEStionable:ENABle 65536")
    assert errors(instrument) == ['-222,"Parameter data out of range"']


# ---------------------------------------------------------------------------
# the commands PyMeasure's classes send that the heater driver does not
# ---------------------------------------------------------------------------
def test_6221_output_low_shield_and_source_delay(supply_6221):
    assert supply_6221.handle(":OUTP:LTE?;:OUTPut:ISHield?;:SOUR:DEL?") == "0;OLOW;1.000000E-03"
    supply_6221.handle("OUTP:LTE 1;:OUTPut:ISHield GUARd;:SOURce:DELay 0.25")
    assert supply_6221.handle(":OUTP:LTE?;:OUTP:ISH?;:SOUR:DEL?") == "1;GUAR;2.500000E-01"
    supply_6221.handle(":SOURce:DELay 0")
    supply_6221.handle("*RST")
    assert supply_6221.handle(":OUTP:LTE?;:OUTP:ISH?;:SOUR:DEL?") == "0;OLOW;1.000000E-03"
    assert errors(supply_6221) == ['-222,"Parameter data out of range"']


def test_2400_measure_configures_the_function_and_turns_the_output_on(supply_2400):
    supply_2400.handle(":SOURce:FUNCtion CURRent;:SOURce:CURRent 0.02;:SENSe:VOLTage:PROTection 5")
    supply_2400.handle(":FORMat:ELEMents VOLTage,CURRent,STATus")
    reply = supply_2400.handle(":MEASure:VOLTage?")
    voltage, current, status = (float(field) for field in reply.split(","))
    assert (voltage, current) == (pytest.approx(1.0), pytest.approx(0.02))   # current: the source level
    assert int(status) == (1 << 15) | (1 << 11) | (1 << 2)         # sourcing I, measuring V, front terminals
    assert supply_2400.output_on
    assert supply_2400.handle(":CONFigure?;:SENSe:VOLTage:PROTection?") == '"VOLT:DC";2.100000E+01'
    assert supply_2400.handle(":ABORt;:SENSe:FUNCtion:CONCurrent?;:SENSe:VOLTage:RANGe:AUTO?") == "1;1"
    supply_2400.handle(":SENSe:VOLTage:RANGe:AUTO OFF;:SENSe:VOLTage:RANGe:AUTO?")
    assert errors(supply_2400) == []


def test_2400_measure_with_the_output_blocked(supply_2400):
    supply_2400.inject_refuse_output()
    assert supply_2400.handle(":MEASure:CURRent?") is None
    assert errors(supply_2400) == ['802,"OUTPUT blocked by output enable"']


def test_2400_auto_output_off_reads_with_the_output_on_only_for_the_reading(supply_2400):
    supply_2400.handle(":SOURce:VOLTage 2;:SENSe:CURRent:PROTection 0.1;:SOURce:CLEar:AUTO ON")
    supply_2400.handle(":FORMat:ELEMents CURRent")
    assert float(supply_2400.handle(":READ?")) == pytest.approx(2.0 / 50.0)
    assert not supply_2400.output_on
    assert supply_2400.handle(":SOURce:DELay 0.5;:SOURce:DELay?;:SOURce:DELay:AUTO?") == "5.000000E-01;0"
    assert errors(supply_2400) == []
