"""The public Python API (``import cryod``) against a real running dry run and real records."""

import io
import os
import subprocess
import sys
import time

import numpy as np
import pytest

import cryod
from tests.example_config import line_of
from tests.scripted_daemon import ScriptedDaemon


def test_import_cryod_exposes_the_documented_api_and_stays_light():
    code = ("import sys, cryod; assert 'numpy' not in sys.modules and 'cryod.service.loop' not in sys.modules; "
            "print(sorted(cryod.__all__))")
    names = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    for name in ("connect", "DaemonClient", "read_record", "record_frame", "load_model", "simulate"):
        assert f"'{name}'" in names
    with pytest.raises(AttributeError, match="no attribute 'regulate'"):
        cryod.regulate


@pytest.mark.system
def test_a_script_steps_the_setpoint_and_waits_until_stable(running_dry_run):
    flange = cryod.connect()
    assert flange.socket == running_dry_run.socket
    while flange.status()["state"] != "closed":          # holding until its first valid readings
        time.sleep(0.05)
    status = flange.ramp(0.0)
    assert status["ramp_K_per_min"] == 0.0
    status = flange.setpoint(5.01)
    assert status["target_K"] == 5.01 and status["setpoint_K"] == 5.01     # the reply shows the new setpoint
    assert flange.status()["setpoint_K"] == 5.01
    started = time.monotonic()
    settled = flange.wait_until_stable(tolerance_K=1e-4, hold_s=30.0, timeout_s=900.0, poll_s=0.01)
    print(f"settled after {time.monotonic() - started:.1f} s of wall time")
    assert settled["state"] == "closed" and settled["setpoint_K"] == 5.01
    assert abs(settled["T2_average_K"] - 5.01) <= 1e-4
    assert abs(settled["T2_K"] - 5.01) < 3e-3                               # one reading: the cooler's line on it
    with pytest.raises(cryod.CommandRefused, match="outside"):
        flange.setpoint(50.0)
    with pytest.raises(ValueError, match="kelvin must be a finite number"):
        flange.setpoint(float("nan"))
    assert flange.status()["target_K"] == 5.01                             # a refusal changes nothing
    flange.heater_off()
    with pytest.raises(cryod.NotStable, match="the loop is off"):
        flange.wait_until_stable(timeout_s=60.0, poll_s=0.05)


def test_waiting_asks_the_average_to_stay_within_tolerance_for_the_hold_and_says_how_far_it_got():
    # the average settles exponentially from 2 mK; the single readings carry the cooler's line
    statuses = [{"time_s": 1.0 * k, "state": "closed", "setpoint_K": 5.0, "target_K": 5.0,
                 "T2_K": 5.0 + 1.5e-3 * np.sin(0.7 * k), "T2_average_K": 5.0 + 2e-3 * np.exp(-k / 20.0)}
                for k in range(400)]
    settled = ScriptedDaemon(statuses).wait_until_stable(tolerance_K=1e-4, hold_s=60.0, sleep=lambda s: None)
    first_within = int(np.ceil(20.0 * np.log(2e-3 / 1e-4)))               # 60 s
    assert settled["time_s"] == first_within + 60
    offset = [dict(status, T2_average_K=status["T2_average_K"] + 5e-4) for status in statuses]
    with pytest.raises(cryod.NotStable, match=r"averaged over 10 s \+50\d\.\d µK from the setpoint"):
        ScriptedDaemon(offset).wait_until_stable(tolerance_K=2e-4, hold_s=60.0, timeout_s=300.0,
                                                 sleep=lambda s: None)


def test_simulate_from_python_gives_the_summary_and_a_record_numpy_and_pandas_read(tmp_path):
    log = io.StringIO()
    run = cryod.simulate(120.0, setpoint_K=5.0, data_dir=tmp_path / "data", socket=tmp_path / "c.sock",
                         window_s=60.0, log_stream=log)
    assert run.exit_code == 0 and run.summary["ticks"] == 1500
    assert "data log: writing" in log.getvalue()
    record = cryod.read_record(run.log_paths[0])
    assert len(record) == 1500 and np.nanmax(record.setpoint_K) == 5.0
    frame = cryod.record_frame(record)
    assert list(frame.columns[:5]) == ["time_s", "T2_K", "T5_K", "heater_W", "setpoint_K"]
    assert np.array_equal(frame["T2_K"].to_numpy(), record.flange_K, equal_nan=True)
    assert frame.attrs["metadata"]["simulated"].startswith("yes")
    model = cryod.load_model()
    assert model.ptc.angular_frequency_rad_s == pytest.approx(10.83, abs=0.05)
    with pytest.raises(cryod.SimulationNotStarted, match="--setpoint 50 K is outside"):
        cryod.simulate(10.0, setpoint_K=50.0, data_dir=tmp_path / "x", socket=tmp_path / "x.sock")


@pytest.mark.system
def test_operator_actions_reach_the_journal_and_the_record_with_who_sent_them(running_dry_run, tmp_path):
    import pwd

    flange = cryod.connect()
    while flange.status()["state"] != "closed":
        time.sleep(0.05)
    flange.setpoint(5.05)
    with pytest.raises(cryod.CommandRefused):
        flange.manual(10.0)                                   # above R I_max^2
    off = flange.heater_off()["state"]
    config = tmp_path / "cryod.yaml"
    config.write_text(config.read_text().replace("integral_W_per_K_s: 4.13 ", "integral_W_per_K_s: 4.0 "))
    assert flange.reload()["state"] == off                     # the heater stays off: a reload is not a setpoint
    config.write_text(config.read_text().replace("period_s: 0.08", "period_s: 0.1"))
    with pytest.raises(cryod.CommandRefused, match="need a restart"):
        flange.reload()
    process = running_dry_run.process
    process.terminate()
    journal = process.communicate(timeout=60)[1]
    who = f"uid {os.getuid()} ({pwd.getpwuid(os.getuid()).pw_name}), pid {os.getpid()}"
    assert f"command setpoint accepted: setpoint 5.05 K (by {who})" in journal
    assert "cryod.loop: warning: command manual refused: " in journal and journal.count(f"(by {who})") == 5
    assert "command heater-off accepted" in journal
    assert f"cryod.daemon: configuration reloaded from {config} (by {who})" in journal
    assert (f"cryod.daemon: error: kept the running configuration: {config}:{line_of(config.read_text(), 'loop:')}: loop: "
            f"changes to loop need a restart" in journal)
    (path,) = (tmp_path / "data").glob("cryod-*.csv")
    events = [text for _, text in cryod.read_record(path).events]
    assert f"event: command: setpoint accepted: setpoint 5.05 K (by {who})" in events


# -- the typed status ---------------------------------------------------------------------------------
def test_the_typed_status_gives_every_key_users_rely_on_and_reads_them_back(tmp_path):
    """One function makes the JSON of ``cryod ctl status --json``: the keys are those of the contract (docs/reference/status.md)
    and of the docs, and reading the JSON back gives the same status."""
    import math

    from cryod.service.daemon_status import DaemonStatus, status_from_json, status_json
    from tests.gated_daemon import GatedDaemon

    with GatedDaemon(tmp_path) as daemon:
        status = daemon.daemon.status()
        data = status_json(status)
    assert list(data)[:10] == ["time_s", "state", "T2_K", "T5_K", "heater_W", "setpoint_K", "target_K",
                               "ramp_K_per_min", "last_target_K", "last_fault"]
    assert {"pi_proportional_W", "pi_integral_W", "ff_W", "ff_line_K", "ticks", "overruns", "lateness_ms_p99",
            "record_path", "setpoint_warning", "alarms", "T2_average_K", "line_amplitude_K"} <= set(data)
    back = status_from_json(data)
    assert back.loop.control == status.loop.control and back.loop.timing == status.loop.timing
    assert back.record_path == status.record_path and back.loop.flange_K == status.loop.flange_K
    assert status_json(back).keys() == data.keys()
    waiting = status_json(DaemonStatus(waiting_for="opening the instruments"))
    assert waiting["state"] == "waiting" and waiting["message"] == "opening the instruments"
    assert waiting["heater_W"] is None and math.isnan(status_from_json(waiting).loop.heater_w)


def test_no_reader_of_the_status_goes_by_string_keys():
    """The status is read by its fields everywhere in cryod; its keys appear in the JSON function only."""
    import re

    from tests.conftest import REPOSITORY

    pattern = re.compile(r"""status(_json\([^)]*\))?\s*(\[\s*["']|\.get\(\s*["'])""")
    offenders = []
    for path in sorted((REPOSITORY / "cryod").rglob("*.py")):
        if path.name == "daemon_status.py" or {"analysis", "identification"} & set(path.parts):
            continue
        for number, line in enumerate(path.read_text().splitlines(), start=1):
            if pattern.search(line):
                offenders.append(f"{path.relative_to(REPOSITORY)}:{number}: {line.strip()}")
    assert not offenders, "\n".join(offenders)
