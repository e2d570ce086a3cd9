"""The Lake Shore 336 command set: the protocol, its TCP server's limits, and the lab's real 336 drivers.

PyMeasure's ``LakeShore3xx`` and QCoDeS's ``LakeshoreModel336`` (in a QCoDeS ``Station``) talk to
cryod as to a 336 over ``TCPIP::127.0.0.1::<port>::SOCKET`` (pyvisa-py): against the daemon with its
loop held between two ticks (their readings are compared with ``ctl status`` of the same tick), and
against a running ``cryod simulate``. A plain socket covers the error paths.
"""

import dataclasses
import logging
import math
import os
import socket
import threading
import time

import numpy as np
import pytest

import cryod
from cryod.config import Lakeshore336Config
from cryod.interfaces.lakeshore336_server import MAX_CLIENTS, MESSAGES_PER_S
from cryod.service.control_socket import send_command
from cryod.service.daemon_status import DaemonStatus, LoopStatus
from cryod.service.lakeshore336 import MAX_MESSAGE, SUPPORTED, Lakeshore336Session, Lakeshore336Setup, split_message
from tests.conftest import REPOSITORY
from tests.dry_run_process import DryRunProcess, lab_config
from tests.gated_daemon import GatedDaemon

STATUS = DaemonStatus(LoopStatus(state="closed", flange_K=5.0001234, ptc_stage_K=3.41, setpoint_K=5.0, target_K=5.0,
                                 last_target_K=5.0, ramp_K_per_min=0.0, heater_w=0.1132, last_fault=None),
                      flange_ohm=1587.2, ptc_stage_ohm=2011.0)


def looped(**changes) -> DaemonStatus:
    """STATUS with the loop's fields changed."""
    return dataclasses.replace(STATUS, loop=dataclasses.replace(STATUS.loop, **changes))


def ask(session, message, status=STATUS):
    """The reply line to one message (None when nothing is answered), as the server builds it."""
    replies = [session.respond(part, status) for part in split_message(message)]
    replies = [reply for reply in replies if isinstance(reply, str)]
    return ";".join(replies) if replies else None


# -- the protocol -----------------------------------------------------------------------------
def test_readings_heater_and_loop_as_the_336_answers_them():
    session = Lakeshore336Session(Lakeshore336Setup.example(), writable=False, peer="test")
    assert ask(session, "*IDN?").split(",")[:2] == ["CRYOD", "MODEL336"]
    assert len(ask(session, "*IDN?").split(",")) == 4
    assert ask(session, "KRDG? A") == "+5.000123" and ask(session, "krdg? b") == "+3.410000"
    assert ask(session, "KRDG? 0") == "+5.000123,+3.410000,+0.000000,+0.000000"
    assert ask(session, "CRDG? A") == f"{5.0001234 - 273.15:+.6f}"
    assert ask(session, "SRDG? A") == "+1587.2000"
    assert ask(session, "RDGST? A;RDGST? C") == "000;001"           # input C is not read: invalid reading
    assert ask(session, "RDGST? A", looped(flange_K=math.nan)) == "001"
    assert ask(session, "HTR? 1") == "+22.640"                       # % of R I_max^2 = 0.5 W
    assert ask(session, "SETP? 1;RAMP? 1;RAMPST? 1;RANGE? 1;OUTMODE? 1") == "+5.000000;0,+0.000;0;3;1,1,0"
    assert ask(session, "RAMPST? 1", looped(setpoint_K=4.9, ramp_K_per_min=0.5)) == "1"
    # Kp 10 W/K over 0.5 W is 2000 %/K; Ki 0.2 W/(K s) is an integral time of 50 s, the 336's reset 1000/50
    assert ask(session, "PID? 1") == "+2000.0,+20.0,+0"
    assert ask(session, "MOUT? 1") == "+0.000"
    assert ask(session, "MOUT? 1", looped(state="manual", heater_w=0.05)) == "+10.000"
    assert ask(session, "TLIMIT? A;TLIMIT? B") == "+25.000;+15.000"
    assert ask(session, "INTYPE? A;INCRV? A;INCRV? C") == "3,1,0,0,1;21;0"
    assert ask(session, "HTRSET? 1") == "0,2,0,+0.100,2"
    off = looped(state="off", setpoint_K=None, target_K=None, heater_w=0.0)
    assert ask(session, "RANGE? 1;OUTMODE? 1;SETP? 1", off) == "0;0,1,0;+5.000000"     # keeps its setpoint
    assert ask(session, "HTRST? 1") == "0"
    assert ask(session, "HTRST? 1", looped(heater_w=math.nan)) == "1"          # heater state unknown
    assert ask(session, "*ESR?") == "000"


def test_errors_go_to_the_event_status_register_and_are_not_answered(caplog):
    session = Lakeshore336Session(Lakeshore336Setup.example(), writable=False, peer="127.0.0.1:4000")
    assert ask(session, "FOO 1") is None and ask(session, "*ESR?") == "032"        # CME, read and cleared
    assert ask(session, "*ESR?") == "000"
    assert ask(session, "KRDG? E") is None and ask(session, "*ESR?") == "016"      # a parameter out of range: EXE
    assert ask(session, "PID? 3") is None and ask(session, "*ESR?") == "016"       # outputs 3, 4 have no PID
    with caplog.at_level(logging.WARNING, logger="cryod.lakeshore336"):
        assert ask(session, "SETP 1,5.2") is None                                # read-only: refused
        assert ask(session, "*RST") is None
    assert ask(session, "*ESR?") == "016"
    assert "SETP" not in caplog.text and "setpoint 5.2 refused: lakeshore336.writable is false (by Lake Shore 336 " \
                                         "interface, 127.0.0.1:4000)" in caplog.text
    assert "*RST refused" in caplog.text
    assert ask(session, "PID 1,10,20,0") is None and ask(session, "*ESR?") == "016"  # settings cryod does not take
    session.respond("*ESE 48", STATUS)
    session.respond("FOO", STATUS)
    assert ask(session, "*ESE?;*STB?") == "048;032" and ask(session, "*CLS;*ESR?") == "000"
    assert ask(session, "*OPC?") == "1"


def test_writes_become_the_operators_commands_with_the_peer():
    session = Lakeshore336Session(Lakeshore336Setup.example(), writable=True, peer="10.0.0.7:5000")
    command = session.respond("SETP 1, +5.200000", STATUS)
    assert (command.name, command.value, command.sender) == ("setpoint", 5.2, "Lake Shore 336 interface, 10.0.0.7:5000")
    assert session.respond("RAMP 1,1,0.5", STATUS).value == 0.5
    assert session.respond("RAMP 1,0,0.5", STATUS).value == 0.0               # ramping off: steps
    assert session.respond("RANGE 1,0", STATUS).name == "heater-off"
    assert session.respond("RANGE 1,3", STATUS) is None                       # already regulating
    off = looped(state="off", target_K=None, last_target_K=5.4)
    again = session.respond("RANGE 1,1", off)
    assert (again.name, again.value) == ("setpoint", 5.4)                     # regulates again at its setpoint
    assert session.respond("RANGE 1,2", dataclasses.replace(off, loop=dataclasses.replace(off.loop, last_target_K=None))) is None  # nothing to regulate to
    assert session.respond("SETP 1,1_5", STATUS) is None                      # numbers as the control socket takes them
    assert ask(session, "*ESR?") == "016"


def test_every_supported_command_is_in_the_reference_beyond_its_generated_list():
    """The page lists the names from the code (a generated list); each must also be said in its words there."""
    text = (REPOSITORY / "docs" / "reference" / "lakeshore336.md").read_text()
    assert "<!-- cryod-table lakeshore336 -->" in text
    text = text.replace("<!-- cryod-table lakeshore336 -->", "")
    for name in SUPPORTED:
        assert f"`{name}" in text, name


# -- the server, with the loop held between ticks ------------------------------------------
def lakeshore_daemon(tmp_path, writable=True, **control):
    return GatedDaemon(tmp_path, sections={"lakeshore336": Lakeshore336Config("127.0.0.1:0", writable)}, **control)


def port_of(daemon) -> int:
    return daemon.port("lakeshore336")


def ask_336(daemon, message: bytes) -> bytes:
    """One query on a connection of its own (the loop stands still meanwhile)."""
    with socket.create_connection(("127.0.0.1", port_of(daemon)), timeout=10) as connection:
        connection.sendall(message)
        return connection.makefile("rb").readline()


def interfaces_at_this_tick(daemon, timeout_s: float = 5.0) -> dict:
    """ctl status of the tick the loop stands at, once the interfaces process has it too (its stream brings it
    within a tenth of a second)."""
    status = send_command(daemon.socket_path, "status")["status"]
    deadline = time.monotonic() + timeout_s
    while abs(float(ask_336(daemon, b"KRDG? A\r\n")) - status["T2_K"]) > 1e-6:
        assert time.monotonic() < deadline, "the interfaces process did not show the tick the loop stands at"
        time.sleep(0.02)
    return status


def converse(daemon, messages: list[bytes], replies: int, timeout_s: float = 20.0) -> list[bytes]:
    """Send ``messages`` on one connection and read ``replies`` lines, letting ticks run while it waits."""
    result = {}

    def client():
        with socket.create_connection(("127.0.0.1", port_of(daemon)), timeout=timeout_s) as connection:
            for message in messages:
                connection.sendall(message)
            stream = connection.makefile("rb")
            result["lines"] = [stream.readline() for _ in range(replies)]

    thread = threading.Thread(target=client)
    thread.start()
    while thread.is_alive():
        daemon.gate.run_ticks(1)
        thread.join(0.005)
    return result["lines"]


@pytest.mark.system
def test_setpoint_through_the_loops_limits_and_journaled_with_the_peer(tmp_path):
    with lakeshore_daemon(tmp_path) as daemon:
        lines = converse(daemon, [b"SETP 1,5.2\r\n", b"SETP? 1;*ESR?\r\n", b"SETP 1,50\r\n", b"SETP? 1;*ESR?\r\n"], 2)
        assert lines == [b"+5.200000;000\r\n", b"+5.200000;016\r\n"]
        assert daemon.loop.regulator.ramp.target_K == 5.2                   # 50 K is above setpoint_max_K: refused
        commands = [event.message for _, event in daemon.gate.events if event.kind == "command"]
        assert any(message.startswith("setpoint accepted: setpoint 5.2 K (by Lake Shore 336 interface, 127.0.0.1:")
                   for message in commands)
        assert any("setpoint refused: setpoint 50 K refused: outside 3..20 K" in message
                   and "(by Lake Shore 336 interface, 127.0.0.1:" in message for message in commands)


@pytest.mark.system
def test_a_read_only_interface_changes_nothing(tmp_path):
    with lakeshore_daemon(tmp_path, writable=False) as daemon:
        before = daemon.regulator_state()
        assert converse(daemon, [b"SETP 1,5.2;RANGE 1,0;RAMP 1,1,2\r\n", b"*ESR?;RANGE? 1\r\n"], 1) == [b"016;3\r\n"]
        assert daemon.regulator_state() == before
        assert daemon.interfaces_journal().count("lakeshore336.writable is false") == 3


@pytest.mark.system
@pytest.mark.skipif(os.geteuid() != 0, reason="a client of another user needs root to start it")
def test_writes_are_taken_only_from_users_that_may_use_the_control_socket(tmp_path):
    """uid 65534, outside the control socket's group (mode 0660, root's): its SETP and RANGE are refused (EXE), said
    in the journal with its uid, and change nothing; its queries are answered. root's SETP is taken."""
    import shutil
    import subprocess
    import sys

    client = ("import socket, sys; connection = socket.create_connection(('127.0.0.1', int(sys.argv[1])), timeout=10); "
              "connection.sendall(b'SETP 1,5.3;RANGE 1,0\\r\\n*ESR?;KRDG? A\\r\\n'); "
              "print(connection.makefile('rb').readline().decode().strip())")
    with lakeshore_daemon(tmp_path) as daemon:
        before = daemon.regulator_state()
        done = subprocess.run([shutil.which("python3", path="/usr/bin:/bin") or sys.executable, "-c", client,
                               str(port_of(daemon))], user=65534, capture_output=True,
                              text=True, timeout=30)
        esr, reading = done.stdout.strip().split(";")
        assert esr == "016" and reading.startswith("+"), done
        daemon.gate.run_ticks(2)
        assert daemon.regulator_state() == before
        journal = daemon.interfaces_journal()
        assert "setpoint 5.3 refused: uid 65534 (nobody) may not use the control socket" in journal
        assert "heater-off refused: uid 65534 (nobody) may not use the control socket" in journal
        lines = converse(daemon, [b"SETP 1,5.2\r\n", b"*ESR?\r\n"], 1)
        assert lines == [b"000\r\n"] and daemon.loop.regulator.ramp.target_K == 5.2
        accepted = [event.message for _, event in daemon.gate.events if event.kind == "command"][-1]
        assert "(by Lake Shore 336 interface, 127.0.0.1:" in accepted and ", uid 0 (root)" in accepted


@pytest.mark.system
def test_garbage_long_lines_and_half_sent_commands_change_nothing(tmp_path):
    with lakeshore_daemon(tmp_path) as daemon:
        before = daemon.regulator_state()
        garbage = bytes(range(256)) * 4 + b"\n"                          # NULs, line feeds, non-ASCII
        flood = b"SETP 1,7" + b"0" * 100_000 + b"\r\n"                   # one message far beyond 255 characters
        lines = converse(daemon, [garbage, flood, b"S" * (MAX_MESSAGE + 1) + b"\n", b"*ESR?;SETP? 1\r\n"], 1)
        assert lines == [b"032;+5.000000\r\n"]
        with socket.create_connection(("127.0.0.1", port_of(daemon))) as connection:
            connection.sendall(b"SETP 1,6")                              # the client goes away mid-command
        daemon.gate.run_ticks(5)
        assert daemon.regulator_state() == before
        assert daemon.loop.exit_code is None and daemon.gate.rows[-1].state.startswith("closed")


@pytest.mark.system
def test_idle_connections_however_many_never_keep_a_client_out(tmp_path):
    """The 16 places taken by connections that said something once and then nothing: one more takes the place of
    the one idle longest, and is served; so do 30 more."""
    with lakeshore_daemon(tmp_path) as daemon:
        port = port_of(daemon)
        held = [socket.create_connection(("127.0.0.1", port), timeout=10) for _ in range(MAX_CLIENTS)]
        try:
            for connection in held:                                     # every one is served
                connection.sendall(b"*OPC?\r\n")
                assert connection.recv(16) == b"1\r\n"
            for _ in range(30):
                with socket.create_connection(("127.0.0.1", port), timeout=10) as extra:
                    extra.sendall(b"*OPC?\r\n")
                    assert extra.recv(16) == b"1\r\n"
            assert held[0].recv(16) == b""                              # the idlest gave its place
        finally:
            for connection in held:
                connection.close()


@pytest.mark.system
def test_a_flood_of_queries_is_served_at_a_bounded_rate(tmp_path):
    with lakeshore_daemon(tmp_path) as daemon:
        daemon.gate.open()
        count = 2 * MESSAGES_PER_S + 10
        with socket.create_connection(("127.0.0.1", port_of(daemon)), timeout=10) as connection:
            connection.sendall(b"KRDG? A\r\n" * count)
            stream = connection.makefile("rb")
            started = time.monotonic()
            for _ in range(count):
                assert stream.readline().startswith(b"+")
            # more than two seconds' worth at MESSAGES_PER_S, however fast the client sends
            assert time.monotonic() - started > 1.5


# -- the real drivers, on the daemon held between ticks: their readings are the tick's ----------------
@pytest.mark.system
def test_pymeasure_and_qcodes_read_what_ctl_status_shows_at_the_same_tick(tmp_path):
    pymeasure_lakeshore = pytest.importorskip("pymeasure.instruments.lakeshore")
    qcodes_336 = pytest.importorskip("qcodes.instrument_drivers.Lakeshore")
    with lakeshore_daemon(tmp_path) as daemon:
        daemon.gate.run_ticks(80)                       # ten cooler cycles: the heater's level is known
        resource = f"TCPIP::127.0.0.1::{port_of(daemon)}::SOCKET"
        controller = pymeasure_lakeshore.LakeShore3xx(resource, visa_library="@py", timeout=10_000)
        qcodes = qcodes_336.LakeshoreModel336("tick_336", resource, visalib="@py", timeout=10)
        try:
            for _ in range(3):
                status = interfaces_at_this_tick(daemon)
                assert controller.input_A.kelvin == pytest.approx(status["T2_K"], abs=1e-6)
                assert qcodes.A.temperature() == pytest.approx(status["T2_K"], abs=1e-6)
                assert qcodes.B.temperature() == pytest.approx(status["T5_K"], abs=1e-6)
                assert controller.output_1.output == pytest.approx(100 * status["heater_mean_W"] / 0.5, abs=1e-3)
                daemon.gate.run_ticks(1)
        finally:
            controller.adapter.close()
            qcodes.close()


# -- against a running `cryod simulate` -------------------------------------------------------------
@pytest.fixture
def dry_run(tmp_path):
    process = DryRunProcess(tmp_path, lab_config(tmp_path), "--speed", "max", "--duration", "200000")
    status = {}
    deadline = time.monotonic() + 60
    while status.get("state") != "closed":
        assert time.monotonic() < deadline, process.journal()[-2000:]
        status = send_command(process.socket, "status")["status"]
        time.sleep(0.05)
    yield process
    assert process.stop() in (0, -15)


def status_the_interfaces_have(process) -> dict:
    """A status the interfaces process has certainly taken: ctl status, then a few of its stream's lines later
    (on --speed max the loop runs many ticks per line, so a reading is a tick since this one, not since now)."""
    status = send_command(process.socket, "status")["status"]
    time.sleep(0.3)
    return status


def reading_was_a_tick_between(process, reading_K, before, after):
    """The reading is the T2 of a row the loop made between two statuses (to the record's 0.1 µK)."""
    deadline = time.monotonic() + 30
    while True:
        record = cryod.read_record(sorted(process.data.glob("cryod-*.csv"))[-1])
        if (record.time_s.size and record.time_s[-1] >= after["time_s"]) or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    window = (record.time_s >= before["time_s"] - 1e-6) & (record.time_s <= after["time_s"] + 1e-6)
    assert window.any()
    return np.min(np.abs(record.flange_K[window] - reading_K)) < 1e-6


@pytest.mark.system
def test_pymeasure_reads_sets_and_waits_and_a_setpoint_above_the_limit_leaves_it(dry_run):
    from pymeasure.instruments.lakeshore import LakeShore3xx

    controller = LakeShore3xx(f"TCPIP::127.0.0.1::{dry_run.ports['lakeshore336']}::SOCKET", visa_library="@py",
                              timeout=10_000)
    try:
        before = status_the_interfaces_have(dry_run)
        reading = controller.input_A.kelvin
        after = send_command(dry_run.socket, "status")["status"]
        assert reading_was_a_tick_between(dry_run, reading, before, after)
        controller.output_1.setpoint = 5.05
        assert controller.output_1.setpoint == pytest.approx(5.05)
        assert send_command(dry_run.socket, "status")["status"]["target_K"] == pytest.approx(5.05)
        controller.input_A.wait_for_temperature(5.05, accuracy=0.02, interval=0.05, timeout=120)
        controller.output_1.setpoint = 30.0                     # above control.setpoint_max_K 20 K
        assert controller.output_1.setpoint == pytest.approx(5.05)
        assert send_command(dry_run.socket, "status")["status"]["target_K"] == pytest.approx(5.05)
        assert controller.ask("*ESR?").strip() == "016"        # the 336's execution error: the client can tell
        assert controller.output_1.range == "high"
        levels = [controller.output_1.output for _ in range(30)]   # the output's level, not the waveform's instant
        assert max(levels) - min(levels) < 10.0 and 5.0 < sum(levels) / 30 < 60.0, levels
    finally:
        controller.adapter.close()
    journal = dry_run.journal()
    assert "command setpoint accepted: setpoint 5.05 K (by Lake Shore 336 interface, 127.0.0.1:" in journal
    assert "command setpoint refused: setpoint 30 K refused: outside 3..20 K" in journal


@pytest.mark.system
def test_qcodes_station_reads_sets_and_waits_until_the_setpoint_is_reached(dry_run, caplog):
    from qcodes.instrument_drivers.Lakeshore import LakeshoreModel336
    from qcodes.station import Station

    with caplog.at_level(logging.WARNING):
        lakeshore = LakeshoreModel336("cryod_336", f"TCPIP::127.0.0.1::{dry_run.ports['lakeshore336']}::SOCKET",
                                      visalib="@py", timeout=10)
        station = Station(lakeshore)                             # takes a snapshot: every parameter is queried
    try:
        assert "Could not update" not in caplog.text, caplog.text
        assert lakeshore.IDN()["vendor"] == "CRYOD" and lakeshore.IDN()["model"] == "336"          # QCoDeS drops "MODEL"
        snapshot = station.snapshot()["instruments"]["cryod_336"]
        assert snapshot["submodules"]["A"]["parameters"]["units"]["value"] == "kelvin"
        assert lakeshore.output_1.output_range() == "high" and lakeshore.output_1.mode() == "closed_loop"
        before = status_the_interfaces_have(dry_run)
        reading = lakeshore.A.temperature()
        after = send_command(dry_run.socket, "status")["status"]
        assert reading_was_a_tick_between(dry_run, reading, before, after)
        lakeshore.output_1.setpoint(4.95)
        assert lakeshore.output_1.setpoint() == pytest.approx(4.95)          # a query waits for the writes before it
        assert send_command(dry_run.socket, "status")["status"]["target_K"] == pytest.approx(4.95)
        lakeshore.output_1.wait_until_set_point_reached(wait_cycle_time=0.05, wait_tolerance=2e-4,
                                                        wait_equilibration_time=0.5)
        assert abs(lakeshore.A.temperature() - 4.95) < 4.95 * 2e-4 + 2e-3
        lakeshore.output_1.setpoint(25.0)                       # above the limit: the setpoint stays
        assert lakeshore.output_1.setpoint() == pytest.approx(4.95)
        assert send_command(dry_run.socket, "status")["status"]["target_K"] == pytest.approx(4.95)
        lakeshore.output_1.output_range("off")                   # RANGE 1,0: cryod's own heater-off
        assert lakeshore.output_1.output_range() == "off"
        assert send_command(dry_run.socket, "status")["status"]["state"] == "off"
        lakeshore.output_1.output_range("high")                  # regulate again at its setpoint
        assert lakeshore.output_1.output_range() == "high"
        assert send_command(dry_run.socket, "status")["status"]["target_K"] == pytest.approx(4.95)
    finally:
        station.close_all_registered_instruments()
    assert "(by Lake Shore 336 interface, 127.0.0.1:" in dry_run.journal()
