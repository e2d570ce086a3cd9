"""Heater supply drivers against the simulated 6221 and 2400, in process and over TCP."""

import contextlib
import math
import time

import pytest

from drivers.clock import MonotonicClock, VirtualClock
from drivers.errors import (BadReply, ConnectionLost, HeaterCompliance, HeaterLimitRefused, HeaterRefused,
                            IdentityMismatch, InstrumentTimeout)
from drivers.keithley2400 import Keithley2400
from drivers.keithley6221 import Keithley6221
from drivers.transports import InProcessTransport, VisaTransport
from simulated_hw.bench import SimulatedBench
from simulated_hw.scpi_server import ScpiServer

from tests.instruments.conftest import HEATER_RESISTANCE_OHM

DRIVERS = {"6221": Keithley6221, "2400": Keithley2400}


@pytest.fixture(params=sorted(DRIVERS))
def supply(request, clock, flange_curve, ptc_stage_curve):
    """(simulated bench, heater driver) for each supply model."""
    bench = SimulatedBench(clock, flange_curve, ptc_stage_curve, heater_resistance_ohm=HEATER_RESISTANCE_OHM,
                           supply=request.param, noise=False)
    transport = InProcessTransport(bench.heater_supply, "simulated heater supply", timeout_s=0.5)
    heater = DRIVERS[request.param](transport, clock, HEATER_RESISTANCE_OHM, max_current_a=0.1,
                                    voltage_compliance_v=10.0, name="flange heater")
    return bench, heater


def assert_off(bench):
    assert not bench.heater_supply.output_on
    assert bench.cryostat.heater_power_w == 0.0


def test_power_is_applied_as_current_squared_times_resistance(supply, clock):
    bench, heater = supply
    setting = heater.set_power_w(0.110)
    assert setting.current_a == pytest.approx(math.sqrt(0.110 / HEATER_RESISTANCE_OHM), rel=1e-6)
    assert bench.heater_supply.output_on
    assert bench.cryostat.heater_power_w == pytest.approx(0.110, rel=1e-5)


def test_power_reaches_the_cryostat_at_the_instant_of_the_write(supply, clock):
    bench, heater = supply
    clock.advance(10.0)
    heater.set_power_w(0.05)
    assert bench.cryostat.plant.time_s == 10.0
    flange_before_K = bench.cryostat.true_temperatures()[0]
    clock.advance(100.0)
    assert bench.cryostat.true_temperatures()[0] > flange_before_K + 0.01


def test_configure_again_leaves_supply_and_driver_off_then_output_returns_on_demand(supply):
    bench, heater = supply            # what a reconnect does after the supply may have been reset
    heater.set_power_w(0.08)
    heater.configure()
    assert_off(bench)
    assert heater.current_a == 0.0 and not heater.output_is_on
    heater.set_power_w(0.05)          # the output is switched on again, not assumed on
    assert bench.heater_supply.output_on
    assert bench.cryostat.heater_power_w == pytest.approx(0.05, rel=1e-5)


def test_read_back(supply):
    bench, heater = supply
    heater.set_power_w(0.08)
    readback = heater.read_back()
    assert readback.current_a == pytest.approx(0.04, rel=1e-6)
    assert readback.voltage_v == pytest.approx(2.0, rel=1e-6)
    assert readback.power_w == pytest.approx(0.08, rel=1e-5)
    assert readback.voltage_measured is isinstance(heater, Keithley2400)


def test_above_the_maximum_current_is_refused_and_nothing_changes(supply):
    bench, heater = supply
    heater.set_power_w(0.1)
    current_before = bench.heater_supply.current_setpoint_a
    with pytest.raises(HeaterLimitRefused, match="above the 100 mA maximum") as raised:
        heater.set_power_w(0.51)          # 101 mA at 50 ohm
    assert isinstance(raised.value, ValueError)
    assert bench.heater_supply.current_setpoint_a == current_before
    assert bench.heater_supply.output_on
    assert bench.cryostat.heater_power_w == pytest.approx(0.1, rel=1e-5)


@pytest.mark.parametrize("power", [-1e-3, math.nan, math.inf])
def test_negative_or_non_finite_power_is_refused(supply, power):
    bench, heater = supply
    with pytest.raises(HeaterLimitRefused):
        heater.set_power_w(power)
    assert not bench.heater_supply.output_on


def test_maximum_power_is_accepted(supply):
    bench, heater = supply
    heater.set_power_w(heater.max_power_w)
    assert bench.cryostat.heater_power_w == pytest.approx(0.5, rel=1e-5)


def test_configuration_that_cannot_reach_the_maximum_current_is_refused(clock, bench):
    with pytest.raises(ValueError, match="above the 4 V compliance"):
        Keithley6221(InProcessTransport(bench.heater_supply), clock, HEATER_RESISTANCE_OHM, max_current_a=0.1,
                     voltage_compliance_v=4.0)


def test_output_off_on_close_and_on_context_exit(supply):
    bench, heater = supply
    heater.set_power_w(0.1)
    heater.close()
    assert_off(bench)
    heater.transport.reopen()
    with heater:
        heater.set_power_w(0.1)
        assert bench.heater_supply.output_on
    assert_off(bench)


def test_output_off_when_the_caller_fails_inside_the_context(supply):
    bench, heater = supply
    with pytest.raises(RuntimeError):
        with heater:
            heater.set_power_w(0.1)
            raise RuntimeError("loop crashed")
    assert_off(bench)


@pytest.fixture(params=[(model, link) for model in sorted(DRIVERS) for link in ("in process", "TCP")],
                ids=lambda param: f"{param[0]} {param[1]}")
def linked_supply(request, flange_curve, ptc_stage_curve):
    """(bench, heater driver) for each supply, in process on a VirtualClock and over TCP via pyvisa-py."""
    model, link = request.param
    clock = VirtualClock() if link == "in process" else MonotonicClock()
    bench = SimulatedBench(clock, flange_curve, ptc_stage_curve, heater_resistance_ohm=HEATER_RESISTANCE_OHM,
                           supply=model, noise=False)
    with contextlib.ExitStack() as stack:
        if link == "in process":
            transport = InProcessTransport(bench.heater_supply, "simulated heater supply", timeout_s=0.25)
        else:
            server = stack.enter_context(ScpiServer(bench.heater_supply))
            transport = VisaTransport(server.resource_name, timeout_s=0.25)
        heater = DRIVERS[model](transport, clock, HEATER_RESISTANCE_OHM, name="flange heater")
        heater.set_power_w(0.05)
        assert bench.cryostat.heater_power_w == pytest.approx(0.05, rel=1e-5)
        yield bench, heater
        heater.close()


@pytest.mark.parametrize("fault, error, match", [
    ("inject_open_heater", HeaterCompliance, "flange heater.*compliance"),
    ("inject_refuse_output", HeaterRefused, "flange heater"),
    ("inject_no_reply", InstrumentTimeout, "flange heater"),
    ("inject_garbage", BadReply, "flange heater"),
    ("drop_connections", ConnectionLost, "flange heater"),
])
def test_each_fault_is_typed_and_leaves_the_output_off(linked_supply, fault, error, match):
    bench, heater = linked_supply
    if fault == "inject_refuse_output":
        heater.output_off()                        # the refusal shows when the output is turned on
    getattr(bench.heater_supply, fault)()
    if fault == "drop_connections":
        time.sleep(0.05)                           # over TCP, the server closes the socket
    start = bench.clock.now()
    with pytest.raises(error, match=match) as raised:
        heater.set_power_w(0.06)
    assert_off(bench)
    if fault == "inject_no_reply":
        assert bench.clock.now() - start >= 0.25   # the timeout elapsed on the clock
    if fault == "inject_refuse_output" and isinstance(heater, Keithley2400):
        assert raised.value.error_queue == ((802, "OUTPUT blocked by output enable"),)
    if fault == "drop_connections":
        heater.set_power_w(0.02)                   # reopened: the loop may carry on
        assert bench.cryostat.heater_power_w == pytest.approx(0.02, rel=1e-5)


def test_open_heater_found_by_read_back(supply):
    bench, heater = supply
    heater.set_power_w(0.05)
    bench.heater_supply.inject_open_heater()
    with pytest.raises(HeaterCompliance):
        heater.read_back()
    assert_off(bench)


def test_wrong_instrument_is_refused_at_connect(clock, bench):
    with pytest.raises(IdentityMismatch, match="expected a MODEL 2400"):
        Keithley2400(InProcessTransport(bench.heater_supply), clock, HEATER_RESISTANCE_OHM)


def test_2400_emulator_reports_read_with_output_off(clock, flange_curve, ptc_stage_curve):
    bench = SimulatedBench(clock, flange_curve, ptc_stage_curve, supply="2400", noise=False)
    transport = InProcessTransport(bench.heater_supply, timeout_s=0.0)
    with pytest.raises(InstrumentTimeout):
        transport.query(":READ?")
    assert transport.query(":SYSTem:ERRor?") == '803,"Not permitted with OUTPUT off"'
