"""Configurations the running daemon refuses, and why it says so in the record.

The daemon runs in process on virtual time against the simulated bench (as in
tests/test_daemon_faults.py): a reload of a file that cannot be read is refused,
the running configuration stays, and the refusal is a ``# event:`` line of the
data file; a temperature above its limit at start-up holds the heater off and
says why; ``cryod --simulate`` refuses a limit the simulated cryostat is above
with the heater off.
"""

import dataclasses
import os

import numpy as np
import pytest

from cryod.cli import main
from cryod.records.record import read_record
from tests.example_config import EXAMPLE, config_file, line_of, simulate_args, simulated_config
from tests.fault_drills import FaultDrill
from tests.reload_drills import daemon_from_file, reloads_over_the_socket


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
    # who asked is said too: a signal here (docs/how-to/records.md, "Who did what")
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
