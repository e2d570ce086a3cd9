"""The record being written, found and annotated: record_path, notes, cryod plot without a path,
waits that end with a reason, one dry run per socket, and setpoints the heater cannot hold."""

import os
import pwd
import subprocess
import sys
import time

import pytest

import cryod
from cryod.cli import main
from cryod.service.commands import parse_command
from tests.conftest import REPOSITORY
from tests.scripted_daemon import ScriptedDaemon

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system


@pytest.fixture
def dry_run_speed():
    """Ten times real time: these tests need the loop regulating into a record, not the daemon's clock far ahead, and a
    dry run at ``max`` would take a core from the ``cryod`` commands they run beside it."""
    return "10"


def _closed(flange):
    """Wait until the loop regulates and its record is open (the data log's thread opens the file at the first
    row it writes, a moment after the loop's first tick: until then ``record_path`` is null)."""
    deadline = time.monotonic() + 60.0
    while flange.status()["state"] != "closed" or flange.record_path() is None:
        assert time.monotonic() < deadline, "the dry run did not start regulating into a record within 60 s"
        time.sleep(0.05)


def _cryod(*arguments, env_of, timeout=120):
    env = dict(os.environ, PYTHONPATH=str(REPOSITORY), XDG_RUNTIME_DIR=str(env_of.socket.parent.parent))
    return subprocess.run([sys.executable, "-m", "cryod.cli", *arguments], env=env, capture_output=True, text=True,
                          timeout=timeout, cwd=env_of.socket.parent.parent.parent)


def test_the_status_names_the_record_and_a_note_goes_into_it_with_who_sent_it(running_dry_run, capsys):
    """The command line's ``cryod ctl`` and ``cryod plot`` run in this process (found through the fixture's
    ``XDG_RUNTIME_DIR``): what they print and what the daemon records of them."""
    flange = cryod.connect()
    _closed(flange)
    path = flange.record_path()
    assert os.path.isabs(path) and path.endswith(".csv") and flange.status()["record_path"] == path
    flange.note("sample 7 mounted, valve V3 closed")
    assert main(["ctl", "note", "cold", "plate", " swapped"]) == 0
    assert capsys.readouterr().out.strip() == "note written: cold plate  swapped"
    assert main(["ctl", "--json", "status"]) == 0
    assert f'"record_path": "{path}"' in capsys.readouterr().out
    with pytest.raises(cryod.CommandRefused, match="not printable"):
        flange.note("bell \x07")
    with pytest.raises(ValueError, match="line break"):
        flange.note("two\nlines")
    with pytest.raises(cryod.CommandRefused, match="takes 1 argument"):
        flange.note("   ")
    assert main(["plot"]) == 0                                          # no path: the record being written
    figure = capsys.readouterr().out.strip()
    assert figure == path.removesuffix(".csv") + ".png" and os.path.getsize(figure)
    process = running_dry_run.process
    process.terminate()
    journal = process.communicate(timeout=60)[1]
    name = pwd.getpwuid(os.getuid()).pw_name
    me = f"uid {os.getuid()} ({name}), pid {os.getpid()}"
    assert f"cryod.notes: note: sample 7 mounted, valve V3 closed (by {me})" in journal
    events = [text for _, text in cryod.read_record(path).events]
    assert f"event: note: sample 7 mounted, valve V3 closed (by {me})" in events
    assert any(text.startswith("event: note: cold plate  swapped (by uid") for text in events)


def test_a_note_is_the_rest_of_the_line():
    assert parse_command("note  run 3:  cold plate \t").value == "run 3:  cold plate"
    with pytest.raises(ValueError, match="'note' takes 1 argument"):
        parse_command("note")


def test_a_setpoint_the_heater_cannot_hold_is_said_and_a_second_dry_run_on_the_socket_is_refused(running_dry_run):
    second = _cryod("simulate", "--speed", "max", "--duration", "10", "--json", env_of=running_dry_run)
    assert second.returncode == 2 and second.stdout == ""                 # one line, no summary
    assert second.stderr == (f"cryod: another cryod (process {running_dry_run.process.pid}) is using the control "
                             f"socket {running_dry_run.socket}: stop that dry run, or give this one a socket of its "
                             f"own with --socket PATH\n")
    flange = cryod.connect()
    _closed(flange)
    reply = flange.command("setpoint 16")
    assert reply["ok"] and "warning: setpoint 16 K needs about 1726 mW" in reply["message"]
    assert "R I_max^2 = 500 mW: it holds the flange at about 7.64 K at most" in reply["message"]
    assert reply["status"]["setpoint_warning"].startswith("setpoint 16 K needs about 1726 mW")
    reply = flange.command("setpoint 3.5")
    assert "is below the flange's 4.23 K with the heater at 0 W" in reply["message"]
    reply = flange.command("setpoint 6")
    assert reply["message"] == "setpoint 6 K" and reply["status"]["setpoint_warning"] is None
    process = running_dry_run.process
    process.terminate()
    journal = process.communicate(timeout=60)[1]
    assert "cryod.loop: warning: setpoint 16 K needs about 1726 mW of heater power in steady state" in journal


class GoneDaemon(ScriptedDaemon):
    """Statuses from a list, then the socket is gone."""

    def status(self):
        try:
            return next(self.statuses)
        except StopIteration:
            raise ConnectionError("no cryod daemon listening at /run/x.sock (No such file or directory)") from None


def test_waiting_ends_with_not_stable_and_the_reason_when_the_daemon_goes_away():
    statuses = [{"time_s": float(k), "state": "closed", "setpoint_K": 5.0, "target_K": 5.0,
                 "T2_average_K": 5.0003} for k in range(5)]
    with pytest.raises(cryod.NotStable, match=r"the daemon went away while waiting \(no cryod daemon listening at "
                                              r"/run/x.sock .*\); last seen: T2 averaged over 10 s \+300.0 µK"):
        GoneDaemon(statuses).wait_until_stable(tolerance_K=1e-4, sleep=lambda s: None)


def test_waiting_is_bounded_in_real_time_whatever_the_daemons_clock_does():
    frozen = [{"time_s": 10.0, "state": "closed", "setpoint_K": 5.0, "target_K": 5.0, "T2_average_K": 5.001}] * 100
    wall = iter(range(100))
    with pytest.raises(cryod.NotStable, match=r"after 30 s of real time \(0 s of the daemon's clock\)"):
        ScriptedDaemon(frozen).wait_until_stable(timeout_s=3600.0, wall_timeout_s=30.0, sleep=lambda s: None,
                                                 wall=lambda: float(next(wall)))
