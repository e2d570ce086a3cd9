"""Both thermometers triggered together, every trigger strategy."""

import pytest

from drivers.clock import MonotonicClock, VirtualClock
from drivers.errors import ConnectionLost, InstrumentTimeout, OverflowReading
from drivers.keithley2002 import FourWireSettings, Keithley2002, TriggerSource
from drivers.pair_triggers import (GpibGroupTrigger, HardwareTrigger, PrologixGroupTrigger, SequentialTrigger,
                                   TriggerEvent)
from drivers.thermometer_pair import ThermometerPair
from drivers.transports import InProcessTransport, PrologixAdapter, VisaTransport
from drivers.trigger_lines import SerialControlLine
from simulated_hw.bench import PROLOGIX_ADDRESSES, SimulatedBench
from simulated_hw.trigger_wiring import SimulatedSerialPort, SimulatedTriggerLine

FLANGE = FourWireSettings(range_ohm=20e3, nplc=1.0, autozero=False)
STAGE = FourWireSettings(range_ohm=2e3, nplc=1.0, autozero=False)
RESOLUTION_OHM = 20e3 / 2e7


def make_pair(bench, clock, transports, trigger_for):
    flange = Keithley2002(transports[0], clock, "flange DMM")
    stage = Keithley2002(transports[1], clock, "PTC-stage DMM")
    flange.configure_four_wire_resistance(FLANGE)
    stage.configure_four_wire_resistance(STAGE)
    return ThermometerPair(flange, stage, trigger_for(transports), clock)


def in_process(bench):
    links = bench.in_process_transports()
    return links.flange_dmm, links.ptc_stage_dmm


STRATEGIES = {
    "external edge": lambda bench, clock: lambda transports: HardwareTrigger(
        SerialControlLine(bench.trigger_port, clock), clock),
    "GPIB group trigger": lambda bench, clock: lambda transports: GpibGroupTrigger(
        bench.gpib_interface, transports, clock),
    "*TRG in turn": lambda bench, clock: lambda transports: SequentialTrigger(transports, clock),
}


@pytest.mark.parametrize("strategy", sorted(STRATEGIES))
def test_both_readings_are_taken_at_the_trigger_instant(bench, clock, flange_curve, ptc_stage_curve, strategy):
    pair = make_pair(bench, clock, in_process(bench), STRATEGIES[strategy](bench, clock))
    clock.advance(12.345)
    expected = []
    original_fire = pair.trigger.fire

    def fire_and_note():
        event = original_fire()
        span = pair.flange_dmm.timing.measurement_span_s
        flange_K, stage_K = bench.cryostat.plant.mean_temperatures(span)   # the plant stands at the trigger
        expected.append((flange_curve.resistance_ohm(flange_K), ptc_stage_curve.resistance_ohm(stage_K)))
        return event

    pair.trigger.fire = fire_and_note
    reading = pair.measure()
    assert reading.trigger_time_s == 12.345 and reading.skew_s == 0.0
    assert reading.flange_resistance_ohm == pytest.approx(expected[0][0], abs=RESOLUTION_OHM)
    assert reading.ptc_stage_resistance_ohm == pytest.approx(expected[0][1], abs=RESOLUTION_OHM / 10)
    first_margin = pair.flange_dmm.first_reading_margin_s
    assert pair.reading_delay_s == pair.flange_dmm.earliest_reading_delay_s   # autozero off: no spread
    assert reading.fetched_time_s == pytest.approx(12.345 + pair.reading_delay_s + 0.0005 + first_margin)
    second = pair.measure()
    assert second.fetched_time_s - second.trigger_time_s == pytest.approx(pair.reading_delay_s + 0.0005)


@pytest.mark.parametrize("strategy, source", [("external edge", "EXTERNAL"), ("GPIB group trigger", "BUS"),
                                              ("*TRG in turn", "BUS")])
def test_prepare_sets_the_dmm_trigger_source(bench, clock, strategy, source):
    pair = make_pair(bench, clock, in_process(bench), STRATEGIES[strategy](bench, clock))
    pair.prepare()
    assert bench.flange_dmm.trigger_source == bench.ptc_stage_dmm.trigger_source == source


def test_trigger_link_line(bench, clock):
    line = SimulatedTriggerLine([bench.flange_dmm, bench.ptc_stage_dmm], kind="trigger_link", link_line=3)
    port = SimulatedSerialPort(line, wired="dtr")
    pair = make_pair(bench, clock, in_process(bench), lambda transports: HardwareTrigger(
        SerialControlLine(port, clock, line="dtr"), clock, dmm_input=TriggerSource.TRIGGER_LINK,
        link_input_line=3))
    reading = pair.measure()
    assert line.pulses == 1 and reading.skew_s == 0.0
    assert bench.flange_dmm.trigger_source == "TLINK" and bench.flange_dmm.link_input_line == 3
    assert bench.flange_dmm.link_output_line != 3


class SlowBus(InProcessTransport):
    """An in-process transport whose writes take bus time on the virtual clock."""

    write_time_s = 0.0015

    def write(self, command):
        super().write(command)
        self.clock.advance(self.write_time_s)


def test_sequential_trigger_measures_the_skew(bench, clock, flange_curve, ptc_stage_curve):
    transports = (SlowBus(bench.flange_dmm, "flange"), SlowBus(bench.ptc_stage_dmm, "stage"))
    pair = make_pair(bench, clock, transports, lambda t: SequentialTrigger(t, clock))
    pair.prepare()
    reading = pair.measure()
    assert reading.skew_s == pytest.approx(SlowBus.write_time_s)
    flange_start = bench.flange_dmm._readings[-1].timestamp_s
    stage_start = bench.ptc_stage_dmm._readings[-1].timestamp_s
    assert stage_start - flange_start == pytest.approx(reading.skew_s)
    assert reading.trigger_time_s == pytest.approx(flange_start + SlowBus.write_time_s)


def test_repeated_measurements_advance(noisy_bench, clock):
    pair = make_pair(noisy_bench, clock, in_process(noisy_bench), STRATEGIES["external edge"](noisy_bench, clock))
    times = []
    for cycle in range(25):
        clock.sleep_until(cycle * 0.08)
        times.append(pair.measure().trigger_time_s)
    assert times == pytest.approx([0.08 * k for k in range(25)])
    assert pair.flange_dmm.last_reading_number == 24


def test_overflow_on_one_thermometer_names_it(bench, clock):
    pair = make_pair(bench, clock, in_process(bench), STRATEGIES["external edge"](bench, clock))
    bench.ptc_stage_dmm.inject_overflow()
    with pytest.raises(OverflowReading, match="PTC-stage DMM"):
        pair.measure()
    assert pair.measure().ptc_stage_resistance_ohm > 0      # the next cycle reads again


def test_silent_dmm_is_a_timeout_and_a_dropped_one_connection_lost(bench, clock):
    pair = make_pair(bench, clock, in_process(bench), STRATEGIES["GPIB group trigger"](bench, clock))
    pair.measure()
    bench.flange_dmm.inject_no_reply()
    with pytest.raises(InstrumentTimeout, match="flange DMM"):
        pair.measure()
    bench.flange_dmm.inject_no_reply(False)
    bench.ptc_stage_dmm.drop_connections()
    with pytest.raises(ConnectionLost, match="PTC-stage DMM"):
        pair.measure()
    pair.ptc_stage_dmm.transport.reopen()
    assert pair.measure().ptc_stage_resistance_ohm > 0


def test_hardware_trigger_refuses_a_bus_source(clock, bench):
    with pytest.raises(ValueError):
        HardwareTrigger(SerialControlLine(bench.trigger_port, clock), clock, dmm_input=TriggerSource.BUS)


def test_trigger_event_fields():
    assert TriggerEvent(1.0, 0.002).skew_s == 0.002


# -- over TCP, through pyvisa-py -------------------------------------------------------------------
@pytest.fixture
def real_time_bench(flange_curve, ptc_stage_curve):
    return SimulatedBench(MonotonicClock(), flange_curve, ptc_stage_curve, noise=False)


def test_pair_over_tcp_sockets_with_sequential_trigger(real_time_bench):
    bench, clock = real_time_bench, real_time_bench.clock
    with bench.serve_tcp() as resources:
        transports = (VisaTransport(resources["flange_dmm"], timeout_s=0.5),
                      VisaTransport(resources["ptc_stage_dmm"], timeout_s=0.5))
        pair = make_pair(bench, clock, transports, lambda t: SequentialTrigger(t, clock))
        readings = [pair.measure() for _ in range(3)]
        pair.close()
    for reading in readings:
        assert 2700 < reading.flange_resistance_ohm < 2800 and 650 < reading.ptc_stage_resistance_ohm < 750
        assert 0.0 < reading.skew_s < 0.01          # measured: the second *TRG leaves after the first


def test_pair_through_prologix_group_trigger(real_time_bench):
    bench, clock = real_time_bench, real_time_bench.clock
    with bench.serve_prologix() as controller:
        adapter = PrologixAdapter(controller.interface_resource_name, timeout_s=0.5)
        transports = (adapter.instrument(PROLOGIX_ADDRESSES["flange"], name="flange DMM"),
                      adapter.instrument(PROLOGIX_ADDRESSES["ptc_stage"], name="PTC-stage DMM"))
        pair = make_pair(bench, clock, transports, lambda t: PrologixGroupTrigger(
            adapter, [PROLOGIX_ADDRESSES["flange"], PROLOGIX_ADDRESSES["ptc_stage"]], clock))
        reading = pair.measure()
        pair.close()
        adapter.close()
    assert controller.group_triggers == [(16, 17)]
    assert reading.skew_s == 0.0
    assert bench.flange_dmm._readings[-1].timestamp_s == bench.ptc_stage_dmm._readings[-1].timestamp_s


def test_driver_learns_the_line_sync_and_autozero_delays():
    """With line sync the integration waits for a mains zero crossing the driver cannot know:
    it learns the delay instead of polling every 2 ms through it, reading after reading."""
    from drivers.keithley2002 import FourWireSettings, Keithley2002
    from drivers.pair_triggers import GpibGroupTrigger
    from drivers.thermometer_pair import ThermometerPair
    from simulated_hw.bench import SimulatedBench

    clock = VirtualClock(start_s=0.0137)          # triggers 13.7 ms after a zero crossing: a 6.3 ms wait
    bench = SimulatedBench(clock, seed=2)
    links = bench.in_process_transports()
    dmms = [Keithley2002(link, clock, name) for link, name in ((links.flange_dmm, "flange"),
                                                               (links.ptc_stage_dmm, "stage"))]
    for dmm in dmms:
        dmm.configure_four_wire_resistance(FourWireSettings(range_ohm=20e3, nplc=1, line_sync=True))
    pair = ThermometerPair(*dmms, GpibGroupTrigger(bench.gpib_interface, [links.flange_dmm, links.ptc_stage_dmm],
                                                   clock), clock)
    fetches = []
    original = links.flange_dmm.query

    def counting(command):
        if command == ":FETCh?":
            fetches.append(clock.now())
        return original(command)

    links.flange_dmm.query = counting
    delays = []
    for tick in range(300):
        trigger = 0.0137 + tick * 0.08
        clock.sleep_until(trigger)
        reading = pair.measure()
        delays.append(reading.fetched_time_s - reading.trigger_time_s)
    assert len(fetches) / 300 < 1.6                          # polling every 2 ms would be about 4 per reading
    plain = [d for d in delays[20:] if d < 0.04]
    zeroed = [d for d in delays[20:] if d >= 0.04]
    # a NORMal autozero falls due 200 ms after the last: every third reading at 80 ms
    assert len(zeroed) == pytest.approx(280 / 3, abs=2)
    ready = 0.0063 + 0.022                                    # sync wait, then the reading
    assert max(plain) < ready + 0.0005 + 0.002                # at most one poll late
    assert max(zeroed) < ready + 0.020 + 0.0005 + 0.002       # one integration more for the zero
