"""Every driver method against its exact (command, reply) exchange."""

import math

import pytest

from drivers.errors import (ConnectionLost, HeaterCompliance, HeaterLimitRefused, HeaterOutputOff, HeaterRefused,
                            InstrumentReportedError, InstrumentTimeout)
from drivers.keithley2002 import (DEFAULT_ELEMENTS, DataElement, FilterType, FourWireSettings, Keithley2002,
                                  TriggerSource)
from drivers.keithley2400 import Keithley2400
from drivers.keithley6221 import Keithley6221
from drivers.pair_triggers import SequentialTrigger
from scpi_replay import ProtocolMismatch, ReplayTransport, expected_protocol

IDN_2002 = "KEITHLEY INSTRUMENTS INC.,MODEL 2002,1234567,B02  /A02"
IDN_6221 = "KEITHLEY INSTRUMENTS INC.,MODEL 6221,1234567,A01  /A02"
IDN_2400 = "KEITHLEY INSTRUMENTS INC.,MODEL 2400,1234567,C30   Mar 17 2006 09:29:29/A02  /K/J"
QUEUE_EMPTY = (":SYSTem:ERRor?", '0,"No error"')


def test_replay_transport_fails_on_a_changed_command():
    transport = ReplayTransport([(":SENSe:FRESistance:NPLCycles 1", None)])
    with pytest.raises(ProtocolMismatch, match="expected ':SENSe:FRESistance:NPLCycles 1'"):
        transport.write(":SENS:FRES:NPLC 1")


def test_replay_transport_fails_on_a_missing_exchange():
    transport = ReplayTransport([("*IDN?", IDN_2002), ("*CLS", None)])
    transport.query("*IDN?")
    with pytest.raises(ProtocolMismatch, match="never happened"):
        transport.assert_done()


def dmm(transport, clock):
    return Keithley2002(transport, clock, "flange DMM")


def test_2002_identity_at_connect(clock):
    with expected_protocol([("*IDN?", IDN_2002)]) as transport:
        meter = dmm(transport, clock)
    assert meter.identity.model == "MODEL 2002"


def test_2002_four_wire_configuration(clock):
    with expected_protocol([
        ("*IDN?", IDN_2002),
        ("*CLS", None),
        (":SENSe:FUNCtion 'FRESistance'", None),
        (":SENSe:FRESistance:RANGe:AUTO OFF", None),
        (":SENSe:FRESistance:RANGe 20000", None),
        (":SENSe:FRESistance:NPLCycles 1", None),
        (":SENSe:FRESistance:DIGits 8", None),
        (":SENSe:FRESistance:AVERage:STATe OFF", None),
        (":SENSe:FRESistance:OCOMpensated OFF", None),
        (":SYSTem:AZERo:STATe ON", None),
        (":SYSTem:AZERo:TYPE NORMal", None),
        (":SYSTem:LSYNc:STATe OFF", None),
        (":FORMat:DATA ASCii", None),
        (":FORMat:ELEMents READing,STATus,RNUMber", None),
        (":SYSTem:RNUMber:RESet", None),
        QUEUE_EMPTY,
    ]) as transport:
        dmm(transport, clock).configure_four_wire_resistance(FourWireSettings(range_ohm=20e3, nplc=1))


def test_2002_configuration_with_filter_offset_compensation_and_line_sync(clock):
    settings = FourWireSettings(range_ohm=None, nplc=0.5, digits=7, filter_count=5,
                                filter_type=FilterType.MOVING, autozero=True, autozero_synchronous=True,
                                offset_compensation=True, line_sync=True)
    with expected_protocol([
        ("*IDN?", IDN_2002),
        ("*CLS", None),
        (":SENSe:FUNCtion 'FRESistance'", None),
        (":SENSe:FRESistance:RANGe:AUTO ON", None),
        (":SENSe:FRESistance:NPLCycles 0.5", None),
        (":SENSe:FRESistance:DIGits 7", None),
        (":SENSe:FRESistance:AVERage:STATe ON", None),
        (":SENSe:FRESistance:AVERage:TCONtrol MOVing", None),
        (":SENSe:FRESistance:AVERage:COUNt 5", None),
        (":SENSe:FRESistance:OCOMpensated ON", None),
        (":SYSTem:AZERo:STATe ON", None),
        (":SYSTem:AZERo:TYPE SYNChronous", None),
        (":SYSTem:LSYNc:STATe ON", None),
        (":FORMat:DATA ASCii", None),
        (":FORMat:ELEMents READing,STATus,UNITs,RNUMber", None),
        (":SYSTem:RNUMber:RESet", None),
        QUEUE_EMPTY,
    ]) as transport:
        dmm(transport, clock).configure_four_wire_resistance(
            settings, elements=(DataElement.READING, DataElement.STATUS, DataElement.UNITS,
                                DataElement.READING_NUMBER))


def test_2002_configuration_reports_the_error_queue(clock):
    with expected_protocol([("*IDN?", IDN_2002)] + [(c, None) for c in (
            "*CLS", ":SENSe:FUNCtion 'FRESistance'", ":SENSe:FRESistance:RANGe:AUTO OFF",
            ":SENSe:FRESistance:RANGe 20000", ":SENSe:FRESistance:NPLCycles 1", ":SENSe:FRESistance:DIGits 8",
            ":SENSe:FRESistance:AVERage:STATe OFF", ":SENSe:FRESistance:OCOMpensated OFF",
            ":SYSTem:AZERo:STATe ON", ":SYSTem:AZERo:TYPE NORMal", ":SYSTem:LSYNc:STATe OFF",
            ":FORMat:DATA ASCii", ":FORMat:ELEMents READing,STATus,RNUMber", ":SYSTem:RNUMber:RESet")] + [
        (":SYSTem:ERRor?", '-113,"Undefined header"'),
        (":SYSTem:ERRor?", '-222,"Parameter data out of range"'),
        QUEUE_EMPTY,
    ]) as transport:
        meter = dmm(transport, clock)
        with pytest.raises(InstrumentReportedError) as raised:
            meter.configure_four_wire_resistance()
    assert raised.value.error_queue == ((-113, "Undefined header"), (-222, "Parameter data out of range"))
    assert "flange DMM" in str(raised.value) and '-113,"Undefined header"' in str(raised.value)


@pytest.mark.parametrize("source, token, link", [
    (TriggerSource.BUS, "BUS", []),
    (TriggerSource.EXTERNAL, "EXTernal", []),
    (TriggerSource.IMMEDIATE, "IMMediate", []),
    (TriggerSource.TRIGGER_LINK, "TLINk", [(":TRIGger:TCONfigure:PROTocol ASYNchronous", None),
                                           (":TRIGger:TCONfigure:ASYNchronous:ILINe 3", None),
                                           (":TRIGger:TCONfigure:ASYNchronous:OLINe 1", None)]),
])
def test_2002_trigger_model(clock, source, token, link):
    with expected_protocol([
        ("*IDN?", IDN_2002),
        (":ABORt", None),
        (":INITiate:CONTinuous OFF", None),
        (":ARM:SOURce IMMediate", None),
        (":ARM:COUNt 1", None),
        (":ARM:LAYer2:SOURce IMMediate", None),
        (":ARM:LAYer2:COUNt 1", None),
        (f":TRIGger:SOURce {token}", None),
        (":TRIGger:COUNt 1", None),
        (":TRIGger:DELay 0", None),
        *link,
        QUEUE_EMPTY,
    ]) as transport:
        dmm(transport, clock).configure_trigger(source, link_input_line=3)


def test_2002_initiate_trigger_fetch(clock):
    with expected_protocol([
        ("*IDN?", IDN_2002),
        (":INITiate", None),
        ("<GET>", None),
        (":FETCh?", "+2.75463210E+03N,+00012"),
        (":ABORt", None),
    ]) as transport:
        meter = dmm(transport, clock)
        meter.initiate()
        transport.trigger()
        reading = meter.fetch()
        meter.abort()
    assert reading.resistance_ohm == 2754.6321 and reading.reading_number == 12 and reading.status == "N"


def test_2002_initiate_confirmed_before_a_hardware_trigger(clock):
    """A hardware edge does not travel in the command stream: the DMM must have parsed :INITiate."""
    with expected_protocol([
        ("*IDN?", IDN_2002),
        (":INITiate", None),
        (":INITiate:CONTinuous?", "0"),
    ]) as transport:
        dmm(transport, clock).initiate(confirm=True)


def test_2002_fetch_new_reading_fetches_again_while_the_number_has_not_advanced(clock):
    with expected_protocol([
        ("*IDN?", IDN_2002),
        (":FETCh?", "+2.75463210E+03N,+00012"),
        (":FETCh?", "+2.75463210E+03N,+00012"),
        (":FETCh?", "+2.75470000E+03N,+00013"),
    ]) as transport:
        meter = dmm(transport, clock)
        meter.last_reading_number = None
        first = meter.fetch_new_reading(0.0)
        second = meter.fetch_new_reading(clock.now())
    assert (first.reading_number, second.reading_number) == (12, 13)
    # the first after configuration waits out the longest a reading can take, then a margin
    assert clock.now() == pytest.approx(meter.timing.worst_case_delay_s + meter.earliest_reading_delay_s
                                        + 2 * meter.fetch_margin_s + meter.first_reading_margin_s
                                        + meter.fetch_poll_interval_s)


def test_2002_left_to_examine_later_asks_its_error_queue_only_when_told(clock):
    """In the daemon the heater goes off before a failing DMM is asked anything: the fault leaves the
    driver at once, and the error queue is read when the daemon calls examine()."""
    with expected_protocol([
        ("*IDN?", IDN_2002),
        (":FETCh?", InstrumentTimeout("replay", "no reply within 0.4 s")),
        (":SYSTem:ERRor?", '-230,"Data corrupt or stale"'),
        (":SYSTem:ERRor?", '0,"No error"'),
    ]) as transport:
        meter = dmm(transport, clock)
        meter.examines_faults_at_once = False
        with pytest.raises(InstrumentTimeout) as raised:
            meter.fetch()
        assert transport.position == 2 and raised.value.error_queue == ()
        raised.value.examine()
        raised.value.examine()                      # once
    assert raised.value.error_queue == ((-230, "Data corrupt or stale"),)


def test_2002_error_queue_read(clock):
    with expected_protocol([
        ("*IDN?", IDN_2002),
        (":SYSTem:ERRor?", '-211,"Trigger ignored"'),
        (":SYSTem:ERRor?", '0,"No error"'),
    ]) as transport:
        assert dmm(transport, clock).read_error_queue() == ((-211, "Trigger ignored"),)


def test_2002_declared_settings_read_back(clock):
    with expected_protocol([
        ("*IDN?", IDN_2002),
        (":SENSe:FRESistance:NPLCycles?", "1.000000E+00"),
        (":TRIGger:SOURce?", "BUS"),
        (":TRIGger:COUNt?", "INF"),
        (":SYSTem:AZERo:TYPE?", "SYNC"),
        (":FORMat:ELEMents?", "READ,STAT,RNUM"),
    ]) as transport:
        meter = dmm(transport, clock)
        assert meter.nplc == 1.0
        assert meter.trigger_source is TriggerSource.BUS
        assert meter.trigger_count == math.inf
        assert meter.autozero_synchronous is True
        assert meter.data_elements == DEFAULT_ELEMENTS


def test_2002_out_of_range_settings_are_refused_before_sending(clock):
    with expected_protocol([("*IDN?", IDN_2002)]) as transport:
        meter = dmm(transport, clock)
        for settings in (FourWireSettings(nplc=20), FourWireSettings(range_ohm=3e6), FourWireSettings(digits=10),
                         FourWireSettings(filter_count=101)):
            with pytest.raises(ValueError, match="refused"):
                meter.configure_four_wire_resistance(settings)
        with pytest.raises(ValueError, match="refused"):
            meter.trigger_delay_s = -1.0


def test_sequential_trigger_sends_trg_to_each(clock):
    flange = ReplayTransport([("*TRG", None)])
    stage = ReplayTransport([("*TRG", None)])
    event = SequentialTrigger([flange, stage], clock).fire()
    flange.assert_done()
    stage.assert_done()
    assert event.skew_s == 0.0


# -- heater supplies ----------------------------------------------------------------------
CONFIGURE_6221 = [
    ("*IDN?", IDN_6221),
    ("*CLS", None),
    (":OUTPut:STATe OFF", None),
    (":SOURce:CURRent:RANGe:AUTO OFF", None),
    (":SOURce:CURRent:RANGe 1.000000E-01", None),
    (":SOURce:CURRent:COMPliance 10.00", None),
    (":SOURce:CURRent 0.000000E+00", None),
    QUEUE_EMPTY,
]
#: The off: 0 A, output off and the output state read back, in one program message.
OFF = [(":SOURce:CURRent 0.000000E+00;:OUTPut:STATe OFF;:OUTPut:STATe?", "0")]
OFF_6221 = OFF


def supply_6221(transport, clock):
    return Keithley6221(transport, clock, heater_resistance_ohm=50.0, voltage_compliance_v=10.0, name="heater")


def test_6221_configuration_at_connect(clock):
    with expected_protocol(CONFIGURE_6221) as transport:
        supply_6221(transport, clock)


def test_6221_set_power_first_time_turns_output_on(clock):
    with expected_protocol(CONFIGURE_6221 + [
        (":SOURce:CURRent 4.690416E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":STATus:MEASurement:CONDition?", "2"),
        # with the output on, each setting and its compliance check go in one program message
        (":SOURce:CURRent 1.414214E-02;:OUTPut:STATe?;:STATus:MEASurement:CONDition?", "1;2"),
    ]) as transport:
        heater = supply_6221(transport, clock)
        first = heater.set_power_w(0.110)
        second = heater.set_power_w(0.010)
    assert first.current_a == pytest.approx(math.sqrt(0.110 / 50.0))
    assert second.power_w == pytest.approx(0.010)


def test_6221_read_back_and_output_off(clock):
    with expected_protocol(CONFIGURE_6221 + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":STATus:MEASurement:CONDition?", "2"),
        (":SOURce:CURRent?", "1.000000E-02"),
        (":STATus:MEASurement:CONDition?", "2"),
        *OFF_6221,
    ]) as transport:
        heater = supply_6221(transport, clock)
        heater.set_current_a(0.010)
        readback = heater.read_back()
        heater.output_off()
    assert (readback.current_a, readback.voltage_v, readback.power_w) == pytest.approx((0.01, 0.5, 0.005))
    assert readback.voltage_measured is False


def test_6221_refused_output_is_reported_and_switched_off(clock):
    with expected_protocol(CONFIGURE_6221 + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "0"),
        (":STATus:MEASurement:CONDition?", "0"),
        *OFF_6221,
        QUEUE_EMPTY,
    ]) as transport:
        heater = supply_6221(transport, clock)
        with pytest.raises(HeaterRefused, match="interlock not asserted"):
            heater.set_current_a(0.010)


def test_6221_compliance_is_a_fault_and_switches_off(clock):
    with expected_protocol(CONFIGURE_6221 + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":STATus:MEASurement:CONDition?", "10"),
        *OFF_6221,
        QUEUE_EMPTY,
    ]) as transport:
        heater = supply_6221(transport, clock)
        with pytest.raises(HeaterCompliance, match="compliance"):
            heater.set_current_a(0.010)


def test_6221_limits_refuse_without_sending_anything(clock):
    with expected_protocol(CONFIGURE_6221) as transport:
        heater = supply_6221(transport, clock)
        for power in (0.6, -0.001, math.nan, math.inf):
            with pytest.raises(HeaterLimitRefused):
                heater.set_power_w(power)
        with pytest.raises(ValueError):
            heater.set_current_a(0.2)


def test_6221_close_and_context_exit_switch_off(clock):
    with expected_protocol(CONFIGURE_6221 + OFF_6221) as transport:
        with supply_6221(transport, clock):
            pass
    assert transport.closed


def test_6221_off_of_a_dropped_link_is_confirmed_on_a_new_connection_and_is_an_off(clock):
    """Every link dropped at once (a shared adapter reset): the off fails on the old connection, goes out
    again on a new one and is confirmed there. That is an off, not an unknown state."""
    with expected_protocol(CONFIGURE_6221 + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":STATus:MEASurement:CONDition?", "2"),
        (OFF[0][0], ConnectionLost("replay", "the other end closed the connection")),
        ("<REOPEN>", None),
        *OFF,
    ]) as transport:
        heater = supply_6221(transport, clock)
        heater.set_current_a(0.010)
        clock.advance(1.5)
        assert heater.output_off() == 1.5 and heater.off_failure is None


def test_6221_off_already_confirmed_asks_nothing_and_an_unconfirmed_one_is_not_waited_on_twice(clock):
    with expected_protocol(CONFIGURE_6221 + OFF + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":STATus:MEASurement:CONDition?", "2"),
        (OFF[0][0], InstrumentTimeout("replay", "no reply within 0.4 s")),
        *OFF,                                      # close() tries once more
    ]) as transport:
        heater = supply_6221(transport, clock)
        assert heater.output_off() == 0.0          # read back once...
        assert heater.output_off() == 0.0          # ...then known: nothing sent
        heater.set_current_a(0.010)
        with pytest.raises(InstrumentTimeout):
            heater.output_off()
        with pytest.raises(InstrumentTimeout):     # the state is unknown: said at once, nothing sent
            heater.output_off()
        heater.close()
    assert heater.off_failure is None and heater.off_confirmed_s == 0.0


CONFIGURE_2400 = [
    ("*IDN?", IDN_2400),
    ("*CLS", None),
    (":OUTPut:STATe OFF", None),
    (":SOURce:FUNCtion CURRent", None),
    (":SOURce:CURRent:MODE FIXed", None),
    (":SOURce:CURRent:RANGe 1.000000E-01", None),
    (":SOURce:CURRent 0.000000E+00", None),
    (':SENSe:FUNCtion "VOLTage"', None),
    (":SENSe:VOLTage:PROTection 1.000000E+01", None),
    (":SENSe:VOLTage:RANGe 1.000000E+01", None),
    (":SENSe:VOLTage:NPLCycles 1", None),
    (":SYSTem:RSENse OFF", None),
    (":FORMat:ELEMents VOLTage,CURRent", None),
    QUEUE_EMPTY,
]


def supply_2400(transport, clock):
    return Keithley2400(transport, clock, heater_resistance_ohm=50.0, voltage_compliance_v=10.0, name="heater")


def test_2400_configuration_at_connect(clock):
    with expected_protocol(CONFIGURE_2400) as transport:
        supply_2400(transport, clock)


def test_2400_set_power_read_back_off(clock):
    with expected_protocol(CONFIGURE_2400 + [
        (":SOURce:CURRent 4.690416E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":SENSe:VOLTage:PROTection:TRIPped?", "0"),
        (":READ?", "+2.345208E+00,+4.690416E-02"),
        (":SENSe:VOLTage:PROTection:TRIPped?", "0"),
        *OFF,
    ]) as transport:
        heater = supply_2400(transport, clock)
        heater.set_power_w(0.110)
        readback = heater.read_back()
        heater.output_off()
    assert readback.power_w == pytest.approx(0.110, rel=1e-6) and readback.voltage_measured


def test_6221_compliance_on_a_later_setting_switches_off(clock):
    with expected_protocol(CONFIGURE_6221 + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":STATus:MEASurement:CONDition?", "2"),
        (":SOURce:CURRent 2.000000E-02;:OUTPut:STATe?;:STATus:MEASurement:CONDition?", "1;10"),
        *OFF_6221,
        QUEUE_EMPTY,
    ]) as transport:
        heater = supply_6221(transport, clock)
        heater.set_current_a(0.010)
        with pytest.raises(HeaterCompliance, match="at 20 mA"):
            heater.set_current_a(0.020)
    assert not heater.output_is_on and heater.current_a == 0.0


def test_6221_output_that_went_off_is_a_fault_and_is_left_off(clock):
    """An interlock that opens mid-run turns the output off: the next setting's read-back sees it, and
    the driver leaves the supply at 0 A and off, so nothing comes back when the interlock closes."""
    with expected_protocol(CONFIGURE_6221 + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":STATus:MEASurement:CONDition?", "2"),
        (":SOURce:CURRent 2.000000E-02;:OUTPut:STATe?;:STATus:MEASurement:CONDition?", "0;0"),
        *OFF_6221,
        QUEUE_EMPTY,
    ]) as transport:
        heater = supply_6221(transport, clock)
        heater.set_current_a(0.010)
        with pytest.raises(HeaterOutputOff, match="output went off while driving 20 mA .interlock not asserted"):
            heater.set_current_a(0.020)
    assert not heater.output_is_on and heater.current_a == 0.0


def test_2400_later_settings_carry_their_compliance_query(clock):
    with expected_protocol(CONFIGURE_2400 + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":SENSe:VOLTage:PROTection:TRIPped?", "0"),
        (":SOURce:CURRent 2.000000E-02;:OUTPut:STATe?;:SENSe:VOLTage:PROTection:TRIPped?", "1;0"),
    ]) as transport:
        heater = supply_2400(transport, clock)
        heater.set_current_a(0.010)
        heater.set_current_a(0.020)
    assert heater.current_a == 0.02


def test_2400_blocked_output_reports_802(clock):
    with expected_protocol(CONFIGURE_2400 + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "0"),
        (":SYSTem:ERRor?", '802,"OUTPUT blocked by output enable"'),
        QUEUE_EMPTY,
        *OFF,
    ]) as transport:
        heater = supply_2400(transport, clock)
        with pytest.raises(HeaterRefused) as raised:
            heater.set_current_a(0.010)
    assert raised.value.error_queue == ((802, "OUTPUT blocked by output enable"),)


def test_2400_compliance_is_a_fault(clock):
    with expected_protocol(CONFIGURE_2400 + [
        (":SOURce:CURRent 1.000000E-02", None),
        (":OUTPut:STATe ON", None),
        (":OUTPut:STATe?", "1"),
        (":SENSe:VOLTage:PROTection:TRIPped?", "1"),
        *OFF,
        QUEUE_EMPTY,
    ]) as transport:
        heater = supply_2400(transport, clock)
        with pytest.raises(HeaterCompliance):
            heater.set_current_a(0.010)


@pytest.mark.parametrize("elements", [DEFAULT_ELEMENTS, (DataElement.READING,),
                                      (DataElement.READING, DataElement.STATUS, DataElement.UNITS,
                                       DataElement.TIMESTAMP, DataElement.READING_NUMBER, DataElement.CHANNEL)])
def test_2002_reading_strings_read_alike_in_the_exact_form_and_field_by_field(clock, elements):
    """The driver reads a reply in the 2002's exact form with one pattern: every reply gives the values the
    field-by-field reading gives, or the same error."""
    with expected_protocol([("*IDN?", IDN_2002)]) as transport:
        meter = dmm(transport, clock)
    meter.elements = elements
    units = DataElement.UNITS in elements
    replies = []
    for value in ("+2.754170E+03", "-1.5E-02", "+9.9E37", "1e999", "+2.7E+03", ".5", "7.", "nan", "+2,7E+03"):
        for status in ("N", "R", "O", "n", ""):
            for number in ("+00042", "-7", "x"):
                fields = [value + status + ("OHM4W" if units else "")]
                if DataElement.TIMESTAMP in elements:
                    fields.append("+0012.500000" + ("SECS" if units else ""))
                if DataElement.READING_NUMBER in elements:
                    fields.append(number + ("RDNG#" if units else ""))
                if DataElement.CHANNEL in elements:
                    fields.append("00INTCHAN")
                replies += [",".join(fields), " " + ",".join(fields), ",".join(fields) + ",extra"]

    def read(way, reply):
        try:
            return way(reply)
        except Exception as error:       # noqa: BLE001 - the error is what is compared
            return type(error), str(error)

    for reply in replies:
        assert read(meter._parsed_reading, reply) == read(meter._parsed_field_by_field, reply), reply
