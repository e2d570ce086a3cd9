"""``cryod run --check`` finds every configuration ``cryod run`` would fail on, at its file, line and key, exit 2.

The configuration is the example with its instruments behind a LAN gateway (TCP sockets, no GPIB
card) and its data and socket in a scratch folder; each case changes one line. ``cryod run`` makes
the same checks before it starts anything, so what ``--check`` passes does not fail at start.
"""

import os
import subprocess
import sys
import time

import pytest

from cryod.cli import main
from cryod.config import SOCKET_PATH_MAX_BYTES
from cryod.service.faults import ExitCode
from tests.conftest import CONFIG, REPOSITORY
from tests.example_config import EXAMPLE, config_file
from tests.reload_drills import reloads_over_the_socket
from tests.systemd_units import TEMPLATE, UNIT, unit_sections

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system

#: The example's instruments behind a LAN-to-GPIB gateway, triggered one after the other.
LAN = {"GPIB0::16::INSTR": "TCPIP0::10.0.0.2::1234::SOCKET", "GPIB0::17::INSTR": "TCPIP0::10.0.0.3::1234::SOCKET",
       "GPIB0::12::INSTR": "TCPIP0::10.0.0.4::1234::SOCKET", "trigger: gpib-group": "trigger: sequential"}
FLANGE = "    resource: TCPIP0::10.0.0.2::1234::SOCKET"


def lan_config(tmp_path):
    """The LAN configuration with data and socket in ``tmp_path``; (path, text)."""
    text = EXAMPLE.replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")
    for gpib, lan in LAN.items():
        text = text.replace(gpib, lan)
    text = (text.replace("/var/lib/cryod", str(tmp_path / "data"))
            .replace("/run/cryod/control.sock", str(tmp_path / "run" / "control.sock"))
            .replace("  timeout_s: 1.0 ", f"  lock_directory: {tmp_path / 'locks'}\n  timeout_s: 1.0 "))
    path = tmp_path / "cryod.yaml"
    path.write_text(text)
    return path, text


def cryod(*arguments, timeout=60):
    return subprocess.run([sys.executable, "-m", "cryod.cli", *arguments], capture_output=True, text=True,
                          cwd=REPOSITORY, timeout=timeout, env=dict(os.environ, PYTHONPATH=str(REPOSITORY)))


def not_a_user_here(kind):
    import grp
    import pwd

    lookup = pwd.getpwnam if kind == "user" else grp.getgrnam
    name = f"cryod-no-such-{kind}"
    with pytest.raises(KeyError):
        lookup(name)
    return name


#: (what, replacements, key, reason): what ``cryod run`` failed on at start, silently misread, or waited on
#: for ever. The error is at the line of the replacement's first new line.
SOCKET = "  path: {tmp}/run/control.sock"
REFUSALS = [
    ("octal-looking setpoint", [("  setpoint_K: 5.0", "  setpoint_K: 010")], "control.setpoint_K",
     "'010' has a leading zero: YAML 1.1 reads it as octal 8, YAML 1.2 as 10"),
    ("underscored setpoint", [("  setpoint_K: 5.0", "  setpoint_K: 1_2")], "control.setpoint_K",
     "'1_2' has an underscore: YAML 1.1 reads it as 12, YAML 1.2 as text"),
    ("socket path too long", [(SOCKET, "  path: {tmp}/" + "s" * 110 + ".sock")], "control_socket.path",
     f"a Unix socket's path holds at most {SOCKET_PATH_MAX_BYTES} bytes"),
    ("socket owner missing", [("  # owner: cryod", "  owner: {user}")], "control_socket.owner", "no user"),
    ("socket group missing", [("  # group: cryod", "  group: {group}")], "control_socket.group", "no group"),
    ("socket folder cannot be made", [(SOCKET, "  path: /proc/cryod-check/control.sock")], "control_socket.path",
     "/proc/cryod-check does not exist and user"),
    ("socket path is a file", [(SOCKET, "  path: {tmp}/occupied")], "control_socket.path",
     "exists and is a regular file"),
    ("lock folder cannot be made", [("  lock_directory: {tmp}/locks", "  lock_directory: /proc/cryod-check-locks")],
     "instruments.lock_directory", "/proc/cryod-check-locks does not exist and user"),
    ("resource with a colon missing", [(FLANGE, "    resource: GPIB0::16:INSTR")], "instruments.flange_dmm.resource",
     "'GPIB0::16:INSTR' is not a VISA resource name: the GPIB primary address must be a number"),
    ("GPIB address 61", [(FLANGE, "    resource: GPIB0::61::INSTR")], "instruments.flange_dmm.resource",
     "'GPIB0::61::INSTR': the GPIB primary address must be 0 to 30, got 61"),
    ("an interface for an instrument", [(FLANGE, "    resource: GPIB0::INTFC")], "instruments.flange_dmm.resource",
     "INTFC is an interface, not an instrument"),
    ("two instruments on one address", [("    resource: TCPIP0::10.0.0.3::1234::SOCKET", FLANGE)],
     "instruments.ptc_stage_dmm.resource", "TCPIP0::10.0.0.2::1234::SOCKET is instruments.flange_dmm's already"),
    ("two on one GPIB bus address, spelled two ways", [("    resource: TCPIP0::10.0.0.3::1234::SOCKET",
                                                        "    resource: GPIB0::16::INSTR"),
                                                       (FLANGE, "    resource: GPIB::16::INSTR")],
     "instruments.ptc_stage_dmm.resource", "GPIB0::16::INSTR is instruments.flange_dmm's already: two instruments "
                                           "cannot share an address"),
    ("two behind one Prologix address", [(FLANGE, "    prologix: {{host: 10.0.0.9, address: 12}}"),
                                         ("    resource: TCPIP0::10.0.0.4::1234::SOCKET",
                                          "    prologix: {{host: 10.0.0.9, address: 12}}")],
     "instruments.flange_dmm.prologix.address", "prologix-ethernet:10.0.0.9:gpib12 is instruments.heater_supply's"),
    ("Prologix port that does not exist", [(FLANGE, "    prologix: {{port: /dev/ttyUSB-cryod-none, address: 16}}")],
     "instruments.flange_dmm.prologix.port", "/dev/ttyUSB-cryod-none: no such device"),
    ("Prologix port that is not a device", [(FLANGE, "    prologix: {{port: {tmp}/occupied, address: 16}}")],
     "instruments.flange_dmm.prologix.port", "is a regular file, not a serial device"),
    ("Prologix port that is a device but not a serial port", [(FLANGE, "    prologix: {{port: /dev/null, address: 16}}")],
     "instruments.flange_dmm.prologix.port", "/dev/null is a character device of the kernel's 'mem' class, not a "
                                             "serial device (the 'tty' class)"),
    ("a host the name service does not know", [(FLANGE, "    resource: TCPIP0::cryo-bench-none.invalid::1234::SOCKET")],
     "instruments.flange_dmm.resource", "host 'cryo-bench-none.invalid' is not known to the name service"),
    ("a Prologix adapter the name service does not know", [(FLANGE, "    prologix: {{host: gpib-lan.invalid, address: 16}}")],
     "instruments.flange_dmm.prologix.host", "host 'gpib-lan.invalid' is not known to the name service"),
    ("garbage VISA library", [('  visa_library: "@py"', '  visa_library: "garbage"')], "instruments.visa_library",
     "'garbage' cannot be loaded as a VISA library"),
    ("GPIB group trigger without a GPIB card", [("  trigger: sequential", "  trigger: gpib-group")],
     "instruments.trigger", "gpib-group triggers both DMMs on one GPIB card, but the flange DMM is "
                            "TCPIP0::10.0.0.2::1234::SOCKET"),
    ("ramp too slow to move", [("  ramp_K_per_min: 0.0", "  ramp_K_per_min: 1e-320")], "control.ramp_K_per_min",
     "1e-320 K/min is too slow to move the setpoint"),
]


def refused_case(tmp_path, replacements):
    """The LAN configuration with ``replacements``; (path, text, line of the first new line)."""
    (tmp_path / "occupied").write_text("a file")
    path, text = lan_config(tmp_path)
    names = {"tmp": tmp_path, "user": not_a_user_here("user"), "group": not_a_user_here("group")}
    lines = []
    for old, new in replacements:
        old = old.format(**names)
        assert old in text, old
        lines.append(text.count("\n", 0, text.index(old)) + 1)
        text = text.replace(old, new.format(**names), 1)
    path.write_text(text)
    return path, text, lines[0]


@pytest.mark.parametrize("what, replacements, key, reason", REFUSALS, ids=[case[0] for case in REFUSALS])
def test_check_refuses_what_run_would_fail_on_at_its_file_line_and_key(tmp_path, capsys, what, replacements, key,
                                                                       reason):
    path, _, line = refused_case(tmp_path, replacements)
    assert main(["run", "--config", str(path), "--check"]) == ExitCode.CONFIG
    error = capsys.readouterr().err
    assert f"{path}:{line}: {key}: " in error, error
    assert reason in error, error
    assert error.count("\n") == 1 and "Traceback" not in error


def test_a_pseudo_terminal_for_a_prologix_port_passes(tmp_path, capsys):
    """A pseudo-terminal is a tty the kernel's sysfs does not list (where /dev/null is of class 'mem'): a serial
    device as far as the check can tell without opening it, as a virtual serial port (socat) is."""
    controller, terminal = os.openpty()
    try:
        path, _, _ = refused_case(tmp_path, [(FLANGE, f"    prologix: {{{{port: {os.ttyname(terminal)}, address: 16}}}}")])
        assert main(["run", "--config", str(path), "--check"]) == 0, capsys.readouterr().err
    finally:
        os.close(controller)
        os.close(terminal)


def test_the_lan_configuration_itself_passes(tmp_path, capsys):
    path, _ = lan_config(tmp_path)
    assert main(["run", "--config", str(path), "--check"]) == 0
    assert "valid" in capsys.readouterr().out


def test_check_and_run_as_processes_refuse_with_exit_2_before_starting_anything(tmp_path):
    """As processes: --check refuses with exit 2 and one line; ``cryod run`` itself refuses the same
    configurations before it starts anything: a VISA library it cannot load must not keep it waiting for
    ever, and a socket path too long is exit 2, which systemd does not restart (exit 1 it would)."""
    cases = {case[0]: case for case in REFUSALS}
    for number, what in enumerate(("garbage VISA library", "socket path too long", "octal-looking setpoint")):
        _, replacements, key, _ = cases[what]
        folder = tmp_path / str(number)            # short: the other cases' socket paths stay below the limit
        folder.mkdir()
        path, _, line = refused_case(folder, replacements)
        located = f"{path}:{line}: {key}: "
        for arguments in (("--check",), ("--duration", "30")):
            started = time.monotonic()
            result = cryod("run", "--config", str(path), *arguments)
            assert result.returncode == 2, (what, arguments, result.stderr[-2000:])
            assert located in result.stderr and "Traceback" not in result.stderr, result.stderr[-2000:]
            assert time.monotonic() - started < 30
        assert not (folder / "data").exists()                   # nothing was started


@pytest.mark.parametrize("unit", [UNIT, TEMPLATE])
def test_systemd_does_not_restart_a_configuration_error(unit):
    prevented = unit_sections(unit)["Service"]["RestartPreventExitStatus"].split()
    assert str(int(ExitCode.CONFIG)) in prevented and str(int(ExitCode.DATA_LOG_FAILED)) in prevented


# ---------------------------------------------------------------------------
# special files in the configuration's place
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["fifo", "device", "directory"])
def test_a_configuration_that_is_not_a_regular_file_is_refused_at_once(tmp_path, kind):
    """A named pipe would keep --check waiting for a writer for ever; a device never ends."""
    if kind == "fifo":
        path = tmp_path / "cryod.yaml"
        os.mkfifo(path)
        words = "is a FIFO (named pipe), not a regular file"
    elif kind == "device":
        path, words = "/dev/zero", "is a character device (like /dev/zero or a terminal), not a regular file"
    else:
        path, words = tmp_path, "is a directory, not a regular file"
    result = cryod("run", "--config", str(path), "--check", timeout=30)
    assert result.returncode == 2 and f"{path}: {words}" in result.stderr, result.stderr


def test_a_configuration_replaced_by_a_fifo_does_not_hang_reloads(tmp_path):
    """The file becomes a named pipe: ``cryod ctl reload`` is refused at once (it hung the service thread,
    and no later reload was ever answered); the file back, the next reload is taken."""
    path = config_file(tmp_path)
    good = path.read_text()

    def to_fifo():
        path.unlink()
        os.mkfifo(path)

    def back_to_file():
        path.unlink()
        path.write_text(good.replace("    proportional_W_per_K: 10.0", "    proportional_W_per_K: 12.0"))

    daemon, result, (fifo, file) = reloads_over_the_socket(tmp_path, path, to_fifo, back_to_file)
    assert result.exit_code == 0
    assert not fifo["ok"]
    assert f"{path}: is a FIFO (named pipe), not a regular file" in fifo["message"]
    assert file["ok"], file["message"]
    assert daemon.loop.regulator.term("pi").controller.gains.proportional_w_per_K == 12.0


def test_an_instrument_out_of_reach_at_start_is_named_by_its_key(tmp_path):
    """What ``cryod run`` says while it waits for an instrument names the configuration's key, beside the
    resource pyvisa could not open."""
    import socket

    from cryod.config import load_config
    from drivers.clock import MonotonicClock
    from cryod.service.instruments import open_instruments
    from drivers.errors import ConnectionLost

    with socket.socket() as probe:              # a port nobody listens at
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    path, _ = lan_config(tmp_path)
    path.write_text(path.read_text().replace("TCPIP0::10.0.0.4::1234::SOCKET", f"TCPIP0::127.0.0.1::{port}::SOCKET"))
    with pytest.raises(ConnectionLost) as caught:
        open_instruments(load_config(path), MonotonicClock())
    assert str(caught.value).startswith("heater supply (instruments.heater_supply): "), str(caught.value)


def test_a_folder_systemd_makes_for_the_service_is_a_note_before_the_first_start(tmp_path, capsys, monkeypatch):
    """The unit's RuntimeDirectory= makes /run/cryod when systemd starts the service: --check run before the
    first start notes that it is missing; cryod run by hand, which systemd does not prepare, refuses it. (A
    folder this user cannot make stands in for /run: /proc.)"""
    from pathlib import Path

    from cryod.service import startup_checks

    monkeypatch.setattr(startup_checks, "SYSTEMD_DIRECTORY_ROOTS", (Path("/proc"),))
    path, _, line = refused_case(tmp_path, [(SOCKET, "  path: /proc/cryod-check/control.sock")])
    assert main(["run", "--config", str(path), "--check"]) == 0
    out = capsys.readouterr().out
    assert "note: /proc/cryod-check (control_socket.path) does not exist yet" in out
    assert "systemd makes it when it starts the service" in out
    assert main(["run", "--config", str(path), "--duration", "1"]) == ExitCode.CONFIG
    assert f"{path}:{line}: control_socket.path: /proc/cryod-check does not exist" in capsys.readouterr().err


def test_a_host_name_that_cannot_be_looked_up_now_is_a_note_not_a_refusal(tmp_path, capsys, monkeypatch):
    """A name service that cannot answer (no network yet at boot) settles nothing about a host name: --check
    passes with a note, and the start would wait for the instrument as for an outage. Names the service says do
    not exist are refused (REFUSALS); IP addresses are never looked up."""
    import socket

    from cryod.service import startup_checks

    looked_up = []

    def no_answer(host, *arguments, **keywords):
        looked_up.append(host)
        raise socket.gaierror(socket.EAI_AGAIN, "Temporary failure in name resolution")

    monkeypatch.setattr(startup_checks.socket, "getaddrinfo", no_answer)
    path, _, _ = refused_case(tmp_path, [(FLANGE, "    resource: TCPIP0::cryo-bench.lab::1234::SOCKET")])
    assert main(["run", "--config", str(path), "--check"]) == 0
    out = capsys.readouterr().out
    assert ("note: instruments.flange_dmm.resource: host cryo-bench.lab could not be looked up now (Temporary "
            "failure in name resolution)") in out, out
    assert looked_up == ["cryo-bench.lab"]
