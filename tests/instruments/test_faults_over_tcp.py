"""Issue 3, section 6, over TCP through pyvisa-py: each fault gives its typed error; the heater ends off."""

import time

import pytest

from cryod.clock import MonotonicClock
from drivers.errors import (BadReply, ConnectionLost, HeaterCompliance, HeaterRefused, InstrumentTimeout,
                            OverflowReading)
from drivers.keithley2002 import FourWireSettings, Keithley2002, TriggerSource
from drivers.keithley2400 import Keithley2400
from drivers.keithley6221 import Keithley6221
from drivers.transports import VisaTransport
from simulated_hw.bench import SimulatedBench
from simulated_hw.scpi_server import ScpiServer

TIMEOUT_S = 0.25
HEATERS = {"6221": Keithley6221, "2400": Keithley2400}


def bench_for(supply, flange_curve, ptc_stage_curve):
    return SimulatedBench(MonotonicClock(), flange_curve, ptc_stage_curve, supply=supply, noise=False,
                          heater_resistance_ohm=50.0)


@pytest.fixture
def dmm_over_tcp(flange_curve, ptc_stage_curve):
    bench = bench_for("6221", flange_curve, ptc_stage_curve)
    with ScpiServer(bench.flange_dmm) as server:
        dmm = Keithley2002(VisaTransport(server.resource_name, timeout_s=TIMEOUT_S), bench.clock, "flange DMM")
        dmm.configure_four_wire_resistance(FourWireSettings(range_ohm=20e3, nplc=0.1, autozero=False))
        dmm.configure_trigger(TriggerSource.BUS)
        yield bench, dmm
        dmm.shutdown()


def trigger_and_fetch(dmm):
    dmm.initiate()
    dmm.trigger()
    return dmm.fetch_new_reading(dmm.clock.now())


def test_dmm_reads_over_tcp(dmm_over_tcp):
    bench, dmm = dmm_over_tcp
    assert 2700 < trigger_and_fetch(dmm).resistance_ohm < 2800


def test_dmm_overflow_over_tcp(dmm_over_tcp):
    bench, dmm = dmm_over_tcp
    bench.flange_dmm.inject_overflow()
    with pytest.raises(OverflowReading):
        trigger_and_fetch(dmm)


def test_dmm_garbage_over_tcp(dmm_over_tcp):
    bench, dmm = dmm_over_tcp
    trigger_and_fetch(dmm)
    bench.flange_dmm.inject_garbage()
    with pytest.raises(BadReply, match="flange DMM"):
        trigger_and_fetch(dmm)


def test_dmm_timeout_over_tcp(dmm_over_tcp):
    bench, dmm = dmm_over_tcp
    bench.flange_dmm.inject_no_reply()
    with pytest.raises(InstrumentTimeout, match="flange DMM"):
        dmm.fetch()


def test_dmm_dropped_connection_over_tcp_and_reopen(dmm_over_tcp):
    bench, dmm = dmm_over_tcp
    bench.flange_dmm.drop_connections()
    time.sleep(0.05)
    with pytest.raises(ConnectionLost, match="flange DMM"):
        trigger_and_fetch(dmm)
    dmm.transport.reopen()
    assert trigger_and_fetch(dmm).resistance_ohm > 0


@pytest.fixture(params=sorted(HEATERS))
def heater_over_tcp(request, flange_curve, ptc_stage_curve):
    bench = bench_for(request.param, flange_curve, ptc_stage_curve)
    with ScpiServer(bench.heater_supply) as server:
        transport = VisaTransport(server.resource_name, timeout_s=TIMEOUT_S)
        heater = HEATERS[request.param](transport, bench.clock, 50.0, name="flange heater")
        heater.set_power_w(0.05)
        assert bench.cryostat.heater_power_w == pytest.approx(0.05, rel=1e-5)
        yield bench, heater
        heater.close()


def assert_off(bench):
    assert not bench.heater_supply.output_on and bench.cryostat.heater_power_w == 0.0


@pytest.mark.parametrize("fault, error", [
    ("inject_open_heater", HeaterCompliance),
    ("inject_garbage", BadReply),
    ("inject_no_reply", InstrumentTimeout),
])
def test_heater_faults_over_tcp_leave_the_output_off(heater_over_tcp, fault, error):
    bench, heater = heater_over_tcp
    getattr(bench.heater_supply, fault)()
    with pytest.raises(error, match="flange heater"):
        heater.set_power_w(0.06)
    assert_off(bench)


def test_heater_refusing_output_over_tcp(heater_over_tcp):
    bench, heater = heater_over_tcp
    heater.output_off()
    bench.heater_supply.inject_refuse_output()
    with pytest.raises(HeaterRefused):
        heater.set_power_w(0.06)
    assert_off(bench)


def test_heater_dropped_connection_over_tcp_is_reopened_to_switch_off(heater_over_tcp):
    bench, heater = heater_over_tcp
    bench.heater_supply.drop_connections()
    time.sleep(0.05)
    with pytest.raises(ConnectionLost):
        heater.set_power_w(0.06)
    assert_off(bench)
