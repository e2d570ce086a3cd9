"""Transports: in process, TCP sockets through pyvisa-py, a Prologix controller."""

import time

import pytest

from drivers.clock import MonotonicClock
from drivers.errors import ConnectionLost, InstrumentTimeout
from drivers.keithley2002 import FourWireSettings, Keithley2002, TriggerSource
from drivers.keithley6221 import Keithley6221
from drivers.transports import InProcessTransport, PrologixAdapter, VisaTransport
from simulated_hw.bench import PROLOGIX_ADDRESSES, SimulatedBench
from simulated_hw.scpi_server import ScpiServer

IDN_2002 = "KEITHLEY INSTRUMENTS INC.,MODEL 2002,0000002,B02  /A02"
#: The wait of the tests that an instrument which does not answer times out.
TCP_TIMEOUT_S = 0.25
#: The wait where a reply is expected: room for a loaded machine, never waited out when the instrument answers.
REPLY_WAIT_S = 5.0


@pytest.fixture
def real_time_bench(flange_curve, ptc_stage_curve):
    """Over TCP the instruments answer from server threads: the clock must run by itself."""
    return SimulatedBench(MonotonicClock(), flange_curve, ptc_stage_curve, noise=False)


# -- in process ------------------------------------------------------------------------------
def test_in_process_timeout_costs_the_timeout_on_the_clock(bench, clock):
    transport = InProcessTransport(bench.flange_dmm, "flange", timeout_s=0.3)
    bench.flange_dmm.inject_no_reply()
    with pytest.raises(InstrumentTimeout, match="no reply within 0.3 s"):
        transport.query("*IDN?")
    assert clock.now() == pytest.approx(0.3)


def test_in_process_dropped_connection_and_reopen(bench):
    transport = InProcessTransport(bench.flange_dmm, "flange")
    bench.flange_dmm.drop_connections()
    with pytest.raises(ConnectionLost):
        transport.query("*IDN?")
    with pytest.raises(ConnectionLost):             # stays lost until reopened
        transport.query("*IDN?")
    transport.reopen()
    assert transport.query("*IDN?") == IDN_2002


def test_in_process_trigger_is_a_group_execute_trigger(bench):
    transport = InProcessTransport(bench.flange_dmm)
    transport.trigger()                              # not initiated: the 2002 ignores it
    assert transport.query(":SYSTem:ERRor?") == '-211,"Trigger ignored"'


# -- TCP sockets through pyvisa-py ---------------------------------------------------------------
def test_socket_query_and_settings(real_time_bench):
    with ScpiServer(real_time_bench.flange_dmm) as server:
        transport = VisaTransport(server.resource_name, timeout_s=REPLY_WAIT_S)
        assert transport.query("*IDN?") == IDN_2002
        transport.write(":SENS:FRES:NPLC 2")
        assert transport.query(":SENS:FRES:NPLC?") == "2"
        transport.close()


def test_socket_timeout_is_typed(real_time_bench):
    with ScpiServer(real_time_bench.flange_dmm) as server:
        transport = VisaTransport(server.resource_name, timeout_s=TCP_TIMEOUT_S)
        real_time_bench.flange_dmm.inject_no_reply()
        start = time.monotonic()
        with pytest.raises(InstrumentTimeout, match="no reply within 0.25 s"):
            transport.query("*IDN?")
        assert time.monotonic() - start >= TCP_TIMEOUT_S * 0.9
        transport.close()


def test_socket_dropped_connection_then_reopen(real_time_bench):
    with ScpiServer(real_time_bench.flange_dmm) as server:
        transport = VisaTransport(server.resource_name, timeout_s=TCP_TIMEOUT_S)
        assert transport.query("*IDN?") == IDN_2002
        real_time_bench.flange_dmm.drop_connections()
        time.sleep(0.05)                              # the server closes the socket
        with pytest.raises(ConnectionLost):
            transport.query("*IDN?")
        transport.reopen()
        assert transport.query("*IDN?") == IDN_2002
        transport.close()


@pytest.mark.system
def test_socket_closed_transport_and_unreachable_server(real_time_bench):
    with ScpiServer(real_time_bench.flange_dmm) as server:
        transport = VisaTransport(server.resource_name, timeout_s=REPLY_WAIT_S)
        transport.close()
        with pytest.raises(ConnectionLost, match="closed"):
            transport.query("*IDN?")
        port = server.port
    nobody_listening = VisaTransport(f"TCPIP0::127.0.0.1::{port}::SOCKET", timeout_s=REPLY_WAIT_S)
    with pytest.raises(ConnectionLost, match="refused"):      # pyvisa-py opens; the first I/O fails
        nobody_listening.query("*IDN?")


def test_serial_instrument_resource(real_time_bench):
    """An ASRL resource (a serial port); pyserial's socket:// URL stands in for the cable."""
    with ScpiServer(real_time_bench.flange_dmm) as server:
        transport = VisaTransport(f"ASRLsocket://127.0.0.1:{server.port}::INSTR", timeout_s=REPLY_WAIT_S)
        assert not transport.is_gpib_instrument and not transport.is_socket
        assert transport.query("*IDN?") == IDN_2002
        transport.trigger()                             # no GET on a serial line: *TRG
        assert transport.query(":SYSTem:ERRor?") == '-211,"Trigger ignored"'
        transport.close()


def test_socket_trigger_sends_trg(real_time_bench):
    clock = real_time_bench.clock
    with ScpiServer(real_time_bench.flange_dmm) as server:
        transport = VisaTransport(server.resource_name, timeout_s=REPLY_WAIT_S)
        dmm = Keithley2002(transport, clock, "flange DMM")
        dmm.configure_four_wire_resistance(FourWireSettings(range_ohm=20e3, nplc=0.1, autozero=False))
        dmm.configure_trigger(TriggerSource.BUS)
        dmm.initiate()
        transport.trigger()
        trigger_time = clock.now()                    # the *TRG has left when write returns
        reading = dmm.fetch_new_reading(trigger_time)
        assert 2700 < reading.resistance_ohm < 2800 and reading.reading_number == 0
        dmm.shutdown()


# -- Prologix GPIB-ETHERNET through pyvisa-py ------------------------------------------------------
@pytest.fixture
def prologix(real_time_bench):
    """(simulated controller, adapter) with the bench's instruments at addresses 16, 17 and 24."""
    with real_time_bench.serve_prologix() as controller:
        adapter = PrologixAdapter(controller.interface_resource_name, timeout_s=TCP_TIMEOUT_S)
        yield controller, adapter
        adapter.close()


def test_prologix_switches_address_between_instruments(prologix):
    controller, adapter = prologix
    flange = adapter.instrument(PROLOGIX_ADDRESSES["flange"], name="flange DMM")
    heater = adapter.instrument(PROLOGIX_ADDRESSES["heater"], name="heater")
    assert flange.query("*IDN?") == IDN_2002
    assert "MODEL 6221" in heater.query("*IDN?")
    assert flange.query("*IDN?") == IDN_2002
    addresses = [c for c in controller.controller_commands if c.startswith("addr")]
    assert addresses == ["addr 16", "addr 24", "addr 16"]


def test_prologix_escapes_data_so_a_plus_sign_arrives(prologix):
    controller, adapter = prologix
    heater = adapter.instrument(PROLOGIX_ADDRESSES["heater"])
    heater.write(":SOURce:CURRent +1.000000E-02")
    assert float(heater.query(":SOURce:CURRent?")) == 0.01


def test_prologix_group_trigger_reaches_both_dmms_at_once(real_time_bench, prologix):
    bench, (controller, adapter) = real_time_bench, prologix
    for emulator in (bench.flange_dmm, bench.ptc_stage_dmm):
        for command in (":TRIG:SOUR BUS", ":INIT"):
            emulator.handle(command)
    adapter.trigger([16, 17])
    deadline = time.monotonic() + 1.0
    while controller.group_triggers == [] and time.monotonic() < deadline:
        time.sleep(0.001)
    assert controller.group_triggers == [(16, 17)]
    assert bench.flange_dmm._pending.trigger_time_s == bench.ptc_stage_dmm._pending.trigger_time_s


def test_prologix_timeout_and_dropped_controller_connection(real_time_bench, prologix):
    bench, (controller, adapter) = real_time_bench, prologix
    flange = adapter.instrument(16, name="flange DMM")
    stage = adapter.instrument(17, name="PTC-stage DMM")
    bench.flange_dmm.inject_no_reply()
    with pytest.raises(InstrumentTimeout):
        flange.query("*IDN?")
    bench.flange_dmm.inject_no_reply(False)
    controller.drop_connections()
    time.sleep(0.05)
    with pytest.raises(ConnectionLost):
        flange.query("*IDN?")
    flange.reopen()                                # reconnects the controller once ...
    stage.reopen()                                 # ... the second instrument only reopens itself
    assert adapter.generation == 2
    assert flange.query("*IDN?") == IDN_2002
    assert "MODEL 2002,0000005" in stage.query("*IDN?")


def test_prologix_heater_driver_unchanged(real_time_bench, prologix):
    bench, (controller, adapter) = real_time_bench, prologix
    with Keithley6221(adapter.instrument(24), bench.clock, 50.0, name="heater") as heater:
        heater.set_power_w(0.110)
        assert bench.cryostat.heater_power_w == pytest.approx(0.110, rel=1e-5)
    assert bench.cryostat.heater_power_w == 0.0


def test_prologix_gpib_usb_path_through_pyserial(real_time_bench):
    """The GPIB-USB controller is a serial port; pyserial's socket:// URL stands in for the USB cable."""
    bench = real_time_bench
    with bench.serve_prologix() as controller:
        adapter = PrologixAdapter.usb(f"socket://127.0.0.1:{controller.port}", timeout_s=TCP_TIMEOUT_S)
        assert adapter.interface_resource_name.startswith("PRLGX-ASRL0::")
        flange = adapter.instrument(PROLOGIX_ADDRESSES["flange"], name="flange DMM")
        assert flange.query("*IDN?") == IDN_2002
        adapter.trigger([16, 17])
        deadline = time.monotonic() + 1.0
        while controller.group_triggers == [] and time.monotonic() < deadline:
            time.sleep(0.001)
        assert controller.group_triggers == [(16, 17)]
        flange.close()
        adapter.close()


def test_a_reply_that_comes_after_its_timeout_is_not_taken_for_the_next_one():
    """The late '0,"No error"' of a timed-out query must not be read as the answer to the next query (a
    heater-off's output state), which would end the daemon with the heater state UNKNOWN."""
    import socket as socket_module
    import threading
    import time as time_module

    from drivers.errors import InstrumentTimeout
    from drivers.transports.visa import VisaTransport

    listener = socket_module.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)

    def instrument():
        connection, _ = listener.accept()
        stream = connection.makefile("rwb", buffering=0)
        for number, line in enumerate(stream):
            if line.startswith(b"SYST:ERR?"):
                time_module.sleep(0.3)                   # busy: the answer comes after the client gave up
                connection.sendall(b'0,"No error"\n')
            elif line.startswith(b":OUTP:STAT?"):
                connection.sendall(b"0\n")
        connection.close()

    server = threading.Thread(target=instrument, daemon=True)
    server.start()
    port = listener.getsockname()[1]
    transport = VisaTransport(f"TCPIP0::127.0.0.1::{port}::SOCKET", timeout_s=0.1, name="heater supply")
    try:
        with pytest.raises(InstrumentTimeout):
            transport.query("SYST:ERR?")
        time_module.sleep(0.3)                           # the late reply is now waiting on the socket
        assert transport.query(":OUTP:STAT?") == "0"     # the reply to this query, not the late one
        assert transport.query(":OUTP:STAT?") == "0"
    finally:
        transport.close()
        listener.close()


def test_a_late_reply_through_a_prologix_controller_is_not_taken_for_the_next_one(real_time_bench, monkeypatch):
    """The late-reply rule holds behind a Prologix controller too: the reply to a ``++read`` that came
    after the client gave up is dropped, and the next query gets its own answer. Two guards do it:
    pyvisa-py's Prologix session reads stale input away before each write, and the transport's own
    drain after a timeout (the test passes with either alone)."""
    from simulated_hw.prologix_server import PrologixServer

    slow = {"reads": 1}
    take = PrologixServer._take_output

    def late_output(state):
        if slow["reads"]:
            slow["reads"] -= 1
            time.sleep(0.3)                       # the instrument answers after the client's timeout
        return take(state)

    monkeypatch.setattr(PrologixServer, "_take_output", staticmethod(late_output))
    with real_time_bench.serve_prologix() as controller:
        adapter = PrologixAdapter(controller.interface_resource_name, timeout_s=0.1)
        heater = adapter.instrument(PROLOGIX_ADDRESSES["heater"], name="heater")
        try:
            with pytest.raises(InstrumentTimeout):
                heater.query("SYST:ERR?")
            time.sleep(0.3)                       # the late '0,"No error"' now waits on the socket
            assert "MODEL 6221" in heater.query("*IDN?")
            assert "MODEL 6221" in heater.query("*IDN?")
        finally:
            heater.close()
            adapter.close()
