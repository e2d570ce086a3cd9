"""DMM faults over TCP through pyvisa-py: each fault gives its typed error (docs/explanation/instruments.md).

The heater supplies' faults run both ways in test_heater_supplies.py.
"""

import time

import pytest

from drivers.clock import MonotonicClock
from drivers.errors import BadReply, ConnectionLost, InstrumentTimeout, OverflowReading
from drivers.keithley2002 import FourWireSettings, Keithley2002, TriggerSource
from drivers.transports import VisaTransport
from simulated_hw.bench import SimulatedBench
from simulated_hw.scpi_server import ScpiServer

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system

#: The wait of the test that a silent DMM times out.
TIMEOUT_S = 0.25
#: The wait where a reply is expected: room for a loaded machine, never waited out when the DMM answers.
REPLY_WAIT_S = 5.0


@pytest.fixture
def dmm_over_tcp(flange_curve, ptc_stage_curve):
    bench = SimulatedBench(MonotonicClock(), flange_curve, ptc_stage_curve, noise=False)
    with ScpiServer(bench.flange_dmm) as server:
        dmm = Keithley2002(VisaTransport(server.resource_name, timeout_s=REPLY_WAIT_S), bench.clock, "flange DMM")
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
    dmm.transport.timeout_s = TIMEOUT_S
    bench.flange_dmm.inject_no_reply()
    started = time.monotonic()
    with pytest.raises(InstrumentTimeout, match=r"flange DMM .*: no reply within 0.25 s"):
        dmm.fetch()
    assert time.monotonic() - started >= 0.9 * TIMEOUT_S


def test_dmm_dropped_connection_over_tcp_and_reopen(dmm_over_tcp):
    bench, dmm = dmm_over_tcp
    bench.flange_dmm.drop_connections()
    time.sleep(0.05)
    with pytest.raises(ConnectionLost, match="flange DMM"):
        trigger_and_fetch(dmm)
    dmm.transport.reopen()
    assert trigger_and_fetch(dmm).resistance_ohm > 0
