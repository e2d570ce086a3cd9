"""Configurations the running daemon refuses, and why it says so in the record (issue 15, items 7 and 9).

The daemon runs in process on virtual time against the simulated bench (as in
tests/test_daemon_faults.py): a reload of a file that cannot be read is refused,
the running configuration stays, and the refusal is a ``# event:`` line of the
data file; a temperature above its limit at start-up holds the heater off and
says why; ``cryod --simulate`` refuses a limit the simulated cryostat is above
with the heater off.
"""

import dataclasses
import os
import threading
import time

import numpy as np
import pytest

from cryod.cli import main
from cryod.config import load_config
from cryod.records.columns import Row
from cryod.records.record import read_record
from drivers.clock import VirtualClock
from cryod.service.control_socket import send_command
from cryod.service.daemon import Daemon
from cryod.service.notify import SystemdNotifier
from tests.conftest import CONFIG
from tests.test_config import EXAMPLE, line_of
from tests.test_cli import simulate_args
from tests.test_daemon_faults import FaultDrill, in_tmp, simulated_config


def config_file(tmp_path, text=None):
    path = tmp_path / "cryod.yaml"
    path.write_text((text or EXAMPLE).replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/"))
    return path


def daemon_from_file(tmp_path, path, row_actions, reload_config=None):
    """The daemon on the configuration read from ``path`` (data and socket moved into tmp_path);
    ``row_actions[n](daemon)`` runs after the n-th row, on the loop's thread."""
    config = in_tmp(load_config(path), tmp_path)
    drill = FaultDrill(tmp_path, {}, config=config)
    rows = []
    answers = []

    def tap(item):
        if isinstance(item, Row):
            rows.append(item)
            action = row_actions.get(len(rows))
            if action is not None:
                answers.append(action(daemon))
    daemon = Daemon(config, drill.open_instruments, VirtualClock(), notifier=SystemdNotifier({}), row_taps=[tap],
                    install_signal_handlers=False, reload_config=reload_config)
    return daemon, answers


def rewrite_then_reload(path, old, new):
    def action(daemon):
        text = path.read_text()
        assert old in text
        path.write_text(text.replace(old, new, 1))
        return daemon.reload()          # what SIGHUP does on the service thread
    return action


def test_a_reload_of_a_file_that_cannot_be_read_is_refused_and_recorded(tmp_path):
    """A list as a key, then a 400-digit integer: each reload is refused with file, line and key, is a
    ``# event:`` line of the record, and the loop goes on regulating on the running configuration."""
    path = config_file(tmp_path)
    daemon, answers = daemon_from_file(tmp_path, path, {
        300: rewrite_then_reload(path, "  resistance_ohm: 50.0\n", "  resistance_ohm: 50.0\n  [a, b]: 1\n"),
        600: rewrite_then_reload(path, "  [a, b]: 1\n  max_current_A: 0.1",
                                 "  max_current_A: " + "1" * 400),
    })
    result = daemon.run(120.0)
    assert result.exit_code == 0
    list_key, big_number = answers
    list_line = line_of(EXAMPLE, "resistance_ohm:") + 1
    assert not list_key.ok
    assert f"{path}:{list_line}: heater: a key must be a name, not a list (['a', 'b'])" in list_key.message
    assert not big_number.ok
    assert (f"{path}:{line_of(EXAMPLE, 'max_current_A:')}: heater.max_current_A: must be a number of a sensible "
            f"size, got an integer of 400 digits" in big_number.message)
    record = read_record(result.log_paths[0])
    events = [text for _, text in record.events if "reload" in text]
    # who asked is said too: a signal here (docs/operations.md, "Who did what")
    assert events == [f"event: command: {list_key.message} (by SIGHUP)",
                      f"event: command: {big_number.message} (by SIGHUP)"]
    assert all(event.startswith("event: command: reload refused, keeping the running configuration: ")
               for event in events)
    late = record.time_s > record.time_s[-1] - 30
    assert np.mean(record.flange_K[late]) == pytest.approx(5.0, abs=2e-3)     # still regulating
    assert daemon.config.heater.max_current_A == 0.1


def test_a_reload_that_fails_in_an_unforeseen_way_is_refused_and_recorded(tmp_path):
    def broken_reading():
        raise RuntimeError("the file system said something new")
    path = config_file(tmp_path)
    daemon, answers = daemon_from_file(tmp_path, path, {100: lambda daemon: daemon.reload()},
                                       reload_config=broken_reading)
    result = daemon.run(30.0)
    assert result.exit_code == 0
    (answer,) = answers
    assert not answer.ok
    assert answer.message == (f"reload refused, keeping the running configuration: reading {path} failed: "
                              f"RuntimeError: the file system said something new")
    events = [text for _, text in read_record(result.log_paths[0]).events]
    assert f"event: command: {answer.message} (by SIGHUP)" in events


def test_a_temperature_above_its_limit_at_start_holds_the_heater_off_and_says_why(tmp_path, caplog):
    config = simulated_config(tmp_path)
    config = dataclasses.replace(config, safety=dataclasses.replace(config.safety, ptc_stage_max_K=3.0))
    drill = FaultDrill(tmp_path, {}, config=config)
    assert drill.run(20.0).exit_code == 0
    assert set(drill.states) == {"holding"} and not np.any(drill.record.heater_w)
    holding = [text for _, text in drill.record.events if text.startswith("event: holding:")]
    assert len(holding) == 1                                   # once per hold, not once per reading
    assert "above the limit 3 K (safety.ptc_stage_max_K)" in holding[0] and "T5 3." in holding[0]
    assert any("safety.ptc_stage_max_K" in record.message and record.levelname == "WARNING"
               for record in caplog.records)


@pytest.mark.parametrize("old, new, key", [
    ("  ptc_stage_max_K: 15.0", "  ptc_stage_max_K: 3.4", "safety.ptc_stage_max_K"),
    ("  flange_max_K: 25.0", "  flange_max_K: 4.2", "safety.flange_max_K"),
])
def test_simulate_refuses_a_limit_the_cryostat_is_above_with_the_heater_off(tmp_path, capsys, old, new, key):
    """The shipped model's PTC stage is at 3.34 K, up to 3.464 K with the cooler's oscillation, and its
    flange at 4.23 K: such limits hold the heater off, or stop the run at the cooler's first peak."""
    text = EXAMPLE.replace(old, new)
    if key == "safety.flange_max_K":
        text = text.replace("  setpoint_max_K: 20.0", "  setpoint_max_K: 4.0").replace(
            "  setpoint_K: 5.0", "  setpoint_K: 3.5")
    path = config_file(tmp_path, text)
    assert main(simulate_args(tmp_path, "--config", str(path), "--duration", "20")) == 2
    error = capsys.readouterr().err
    assert f"nothing was started: {path}:{line_of(text, new.strip())}: {key}: " in error
    assert "the heater would never regulate: held off" in error
    assert not (tmp_path / "data").exists()


def reloads_over_the_socket(tmp_path, path, first, second):
    """The daemon on the file at ``path``: ``first()`` changes the file after row 100 and ``second()`` after row
    400, each followed by ``cryod ctl reload`` from a client thread; the loop ticks slowly until the client has
    its answer. Returns the daemon, its result and the two replies."""
    replies = {}
    asking = []

    def reload_over_the_socket(name, change):
        def action(daemon):
            change()
            asking.append(threading.Thread(target=lambda: replies.update(
                {name: send_command(tmp_path / "control.sock", "reload", timeout_s=20.0)})))
            asking[-1].start()
        return action

    def until_answered(name):
        def action(daemon):          # the loop keeps ticking, slowly, until the client has its answer
            if name not in replies:
                time.sleep(0.002)
        return action

    actions = {row: until_answered("first") for row in range(101, 390)}
    actions.update({row: until_answered("second") for row in range(401, 740)})
    actions[100] = reload_over_the_socket("first", first)
    actions[400] = reload_over_the_socket("second", second)
    daemon, _ = daemon_from_file(tmp_path, path, actions, reload_config=lambda: in_tmp(load_config(path), tmp_path))
    result = daemon.run(60.0)
    for thread in asking:
        thread.join(20.0)
    return daemon, result, (replies.get("first"), replies.get("second"))


def replacing(path, old, new):
    def change():
        text = path.read_text()
        assert old in text
        path.write_text(text.replace(old, new, 1))
    return change


def test_cryod_ctl_reload_applies_a_good_file_refuses_a_bad_one_and_says_who_asked(tmp_path):
    """An operator in the socket's group cannot signal a daemon run by root: the socket's ``reload`` does
    what SIGHUP does, and its client gets the answer (the refusal with file, line and key)."""
    path = config_file(tmp_path)
    daemon, result, (good, bad) = reloads_over_the_socket(
        tmp_path, path, replacing(path, "    proportional_W_per_K: 10.0", "    proportional_W_per_K: 12.0"),
        replacing(path, "  max_current_A: 0.1", "  max_current_A: " + "1" * 400))
    assert result.exit_code == 0
    assert good["ok"] and good["message"] == f"configuration reloaded from {path}"
    assert daemon.loop.regulator.term("pi").controller.gains.proportional_w_per_K == 12.0
    assert not bad["ok"]
    assert f"{path}:{line_of(EXAMPLE, 'max_current_A:')}: heater.max_current_A" in bad["message"]
    assert "keeping the running configuration" in bad["message"]
    events = [text for _, text in read_record(result.log_paths[0]).events if "reload" in text]
    assert len(events) == 2
    assert all(f"(by uid {os.getuid()}" in event for event in events), events
