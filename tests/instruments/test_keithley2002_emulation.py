"""The Keithley 2002 driver against the simulated 2002, in process."""

import pytest

from drivers.errors import BadReply, IdentityMismatch, InstrumentTimeout, OverflowReading
from drivers.keithley2002 import FilterType, FourWireSettings, Keithley2002, TriggerSource
from drivers.keithley2002_timing import ReadingTiming
from drivers.transports import InProcessTransport
from simulated_hw.instrument import GARBAGE_REPLY
from simulated_hw.keithley2002 import Keithley2002Emulator

FLANGE_SETTINGS = FourWireSettings(range_ohm=20e3, nplc=1.0, autozero=False)


def flange_dmm(bench, clock, settings=FLANGE_SETTINGS, source=TriggerSource.BUS, timeout_s=1.0):
    transport = InProcessTransport(bench.flange_dmm, "simulated flange DMM", timeout_s=timeout_s)
    dmm = Keithley2002(transport, clock, "flange DMM")
    dmm.configure_four_wire_resistance(settings)
    dmm.configure_trigger(source)
    return dmm


def test_reading_is_the_cernox_resistance_averaged_over_the_integration(bench, clock, flange_curve):
    clock.advance(5.0)
    dmm = flange_dmm(bench, clock)
    dmm.initiate()
    trigger_time = clock.now()
    dmm.transport.trigger()
    # the emulator took the reading at the trigger instant: the plant stands there
    span = dmm.timing.measurement_span_s
    flange_mean_K, _ = bench.cryostat.plant.mean_temperatures(span)
    reading = dmm.fetch_new_reading(trigger_time)
    resolution = 20e3 / (2 * 10 ** 7)
    assert reading.resistance_ohm == pytest.approx(flange_curve.resistance_ohm(flange_mean_K), abs=resolution)
    assert 2700 < reading.resistance_ohm < 2800 and reading.reading_number == 0


def test_ptc_stage_dmm_reads_the_stage_thermometer(bench, clock, ptc_stage_curve):
    dmm = Keithley2002(InProcessTransport(bench.ptc_stage_dmm), clock, "PTC-stage DMM")
    dmm.configure_four_wire_resistance(FourWireSettings(range_ohm=2e3, nplc=1.0, autozero=False))
    dmm.configure_trigger(TriggerSource.BUS)
    dmm.initiate()
    dmm.transport.trigger()
    _, stage_mean_K = bench.cryostat.plant.mean_temperatures(dmm.timing.measurement_span_s)
    reading = dmm.fetch_new_reading(0.0)
    assert reading.resistance_ohm == pytest.approx(ptc_stage_curve.resistance_ohm(stage_mean_K), abs=1e-4)


@pytest.mark.parametrize("settings, expected_s", [
    (FourWireSettings(nplc=1.0, autozero=False), 0.020 + 0.002),
    (FourWireSettings(nplc=2.0, autozero=False), 0.040 + 0.002),
    (FourWireSettings(nplc=1.0, autozero=False, offset_compensation=True), 0.040 + 0.002),
    (FourWireSettings(nplc=1.0, autozero=True, autozero_synchronous=True), 0.040 + 0.002),
    (FourWireSettings(nplc=0.5, autozero=False, filter_count=3, filter_type=FilterType.REPEATING),
     0.030 + 0.002),
])
def test_reading_is_available_only_after_the_instrument_could_have_it(bench, clock, settings, expected_s):
    dmm = flange_dmm(bench, clock, settings, timeout_s=0.0)
    dmm.initiate()
    dmm.transport.trigger()
    clock.sleep_until(expected_s - 1e-4)
    with pytest.raises(InstrumentTimeout) as raised:          # no reading yet: -230, no reply
        dmm.fetch()
    assert raised.value.error_queue == ((-230, "Data corrupt or stale"),)
    clock.sleep_until(expected_s)
    assert dmm.fetch().reading_number == 0
    assert dmm.reading_delay_s == pytest.approx(expected_s)


def test_fetch_before_any_reading_reports_data_stale(bench, clock):
    dmm = flange_dmm(bench, clock)
    with pytest.raises(InstrumentTimeout) as raised:
        dmm.fetch()
    assert raised.value.error_queue == ((-230, "Data corrupt or stale"),)


def test_early_fetch_returns_the_old_reading_and_the_driver_waits_for_the_new_one(bench, clock):
    dmm = flange_dmm(bench, clock)
    dmm.initiate()
    dmm.transport.trigger()
    first = dmm.fetch_new_reading(0.0)
    dmm.initiate()
    trigger_time = clock.now()
    dmm.transport.trigger()
    assert dmm.fetch().reading_number == first.reading_number       # the 2002 still has the old one
    second = dmm.fetch_new_reading(trigger_time)
    assert second.reading_number == first.reading_number + 1


def test_driver_times_out_when_no_new_reading_comes(bench, clock):
    dmm = flange_dmm(bench, clock)
    dmm.initiate()
    dmm.transport.trigger()
    dmm.fetch_new_reading(0.0)
    with pytest.raises(InstrumentTimeout, match="no new reading"):
        dmm.fetch_new_reading(clock.now(), timeout_s=0.05)       # nobody triggered


def test_trigger_during_a_reading_is_ignored_with_211(bench, clock):
    dmm = flange_dmm(bench, clock)
    dmm.initiate()
    dmm.transport.trigger()
    dmm.transport.trigger()
    assert dmm.read_error_queue() == ((-211, "Trigger ignored"),)


def test_wrong_trigger_source_ignores_the_bus_trigger(bench, clock):
    dmm = flange_dmm(bench, clock, source=TriggerSource.EXTERNAL)
    dmm.initiate()
    dmm.transport.trigger()
    assert dmm.read_error_queue() == ((-211, "Trigger ignored"),)
    bench.flange_dmm.external_trigger()
    assert dmm.fetch_new_reading(clock.now()).reading_number == 0


def test_trigger_link_input_line_must_match(bench, clock):
    dmm = Keithley2002(InProcessTransport(bench.flange_dmm), clock, "flange DMM")
    dmm.configure_four_wire_resistance(FLANGE_SETTINGS)
    dmm.configure_trigger(TriggerSource.TRIGGER_LINK, link_input_line=4, link_output_line=1)
    dmm.initiate()
    bench.flange_dmm.trigger_link_pulse(3)
    assert bench.flange_dmm._pending is None
    bench.flange_dmm.trigger_link_pulse(4)
    assert dmm.fetch_new_reading(clock.now()).reading_number == 0


def test_immediate_source_with_continuous_initiation_free_runs(bench, clock):
    dmm = flange_dmm(bench, clock, source=TriggerSource.IMMEDIATE)
    dmm.continuous_initiation = True
    clock.advance(1.0)
    reading = dmm.fetch()
    assert reading.reading_number == 44           # back to back, 22 ms each: 45 done by t = 0.99 s


def test_line_sync_starts_at_the_next_line_cycle(bench, clock):
    dmm = flange_dmm(bench, clock, FourWireSettings(nplc=1.0, autozero=False, line_sync=True))
    clock.advance(0.005)                           # a quarter of a 50 Hz cycle
    dmm.initiate()
    dmm.transport.trigger()
    assert bench.flange_dmm._pending.start_s == pytest.approx(0.020)


def test_moving_filter_averages_successive_readings(bench, clock, flange_curve):
    dmm = flange_dmm(bench, clock, FourWireSettings(nplc=1.0, autozero=False, filter_count=2,
                                                    filter_type=FilterType.MOVING))
    raw, filtered = [], []
    for _ in range(3):
        dmm.initiate()
        trigger_time = clock.now()
        dmm.transport.trigger()
        flange_mean_K, _ = bench.cryostat.plant.mean_temperatures(dmm.timing.measurement_span_s)
        raw.append(flange_curve.resistance_ohm(flange_mean_K))
        filtered.append(dmm.fetch_new_reading(trigger_time).resistance_ohm)
        clock.advance(0.3)
    resolution = 20e3 / 2e7
    assert raw[1] != pytest.approx(raw[0], abs=10 * resolution)        # the PTC line moves T2
    assert filtered[0] == pytest.approx(raw[0], abs=resolution)
    assert filtered[1] == pytest.approx((raw[0] + raw[1]) / 2, abs=resolution)
    assert filtered[2] == pytest.approx((raw[1] + raw[2]) / 2, abs=resolution)


def test_overflow_is_a_typed_error_not_a_temperature(bench, clock):
    dmm = flange_dmm(bench, clock)
    bench.flange_dmm.inject_overflow()
    dmm.initiate()
    dmm.transport.trigger()
    with pytest.raises(OverflowReading) as raised:
        dmm.fetch_new_reading(0.0)
    assert "+9.9E37" in str(raised.value) and "flange DMM" in str(raised.value)


def test_resistance_above_the_range_overflows(bench, clock):
    dmm = flange_dmm(bench, clock, FourWireSettings(range_ohm=2e3, autozero=False))   # 2.75 kohm on 2 kohm
    dmm.initiate()
    dmm.transport.trigger()
    with pytest.raises(OverflowReading):
        dmm.fetch_new_reading(0.0)


def test_garbage_reply_is_a_bad_reply_naming_instrument_and_reply(bench, clock):
    dmm = flange_dmm(bench, clock)
    dmm.initiate()
    dmm.transport.trigger()
    bench.flange_dmm.inject_garbage()
    with pytest.raises(BadReply) as raised:
        dmm.fetch_new_reading(0.0)
    assert raised.value.reply == GARBAGE_REPLY
    assert "flange DMM" in str(raised.value)


def test_identity_mismatch_at_connect(bench, clock):
    with pytest.raises(IdentityMismatch, match="expected a MODEL 2002, found MODEL 6221"):
        Keithley2002(InProcessTransport(bench.heater_supply), clock, "flange DMM")


def test_unknown_command_goes_to_the_error_queue_as_the_2002_reports_it(bench, clock):
    transport = InProcessTransport(bench.flange_dmm)
    transport.write(":SENSe:FRESistance:NPLCycle 1")
    transport.write(":SENS:FRES:NPLC 11")
    transport.write(":SENS:FRES:NPLC one")
    transport.write(":SENS:FUNC 'VOLT:DC'")
    errors = [transport.query(":SYSTem:ERRor?") for _ in range(5)]
    assert errors == ['-113,"Undefined header"', '-222,"Parameter data out of range"',
                      '-104,"Data type error"', '-224,"Illegal parameter value"', '0,"No error"']


def test_emulated_timing_is_the_driver_timing(bench, clock):
    settings = FourWireSettings(nplc=0.2, autozero=True, offset_compensation=True, line_sync=True,
                                filter_count=4)
    dmm = flange_dmm(bench, clock, settings)
    assert bench.flange_dmm.timing == dmm.timing
    assert isinstance(dmm.timing, ReadingTiming)


def test_emulator_rejects_an_unknown_thermometer(bench, flange_curve):
    with pytest.raises(ValueError, match="thermometer"):
        Keithley2002Emulator(bench.cryostat, "sample", flange_curve)


def test_a_fixed_range_reading_string_is_the_manuals_format_for_every_element_layout(bench):
    """The simulated 2002 formats a reading on a fixed range with one pattern made per configuration: the
    text is the manual's (value at the range's resolution, status, units, time stamp, reading number,
    channel) for every layout of elements and every resolution."""
    import itertools

    from simulated_hw.keithley2002 import ELEMENTS, _Reading
    emulator = bench.flange_dmm
    emulator.autorange, emulator.range_ohm = False, 2e4
    for count in range(1, len(ELEMENTS) + 1):
        for chosen in itertools.combinations([element.upper() for element in ELEMENTS], count):
            if "READING" not in chosen:
                continue
            emulator.elements = tuple(element.upper() for element in ELEMENTS if element.upper() in chosen)
            units = "UNITS" in chosen
            for digits in (4, 7, 8, 9):
                emulator.digits = digits
                resolution = 2e4 / (2 * 10 ** (digits - 1))
                for value, number in ((2754.1734, 0), (711.83, 42), (19999.9, 99999), (0.0001, 7)):
                    reading = _Reading(value, False, number, 12.3456789)
                    fields = [f"{round(value / resolution) * resolution:+.{digits - 1}E}"
                              + ("N" if "STATUS" in chosen else "") + ("OHM4W" if units else "")]
                    if "TIMESTAMP" in chosen:
                        fields.append(f"{reading.timestamp_s:+012.6f}" + ("SECS" if units else ""))
                    if "RNUMBER" in chosen:
                        fields.append(f"{number:+06d}" + ("RDNG#" if units else ""))
                    if "CHANNEL" in chosen:
                        fields.append("00" + ("INTCHAN" if units else ""))
                    assert emulator._format(reading) == ",".join(fields)
