"""Alarms: their settings, each alarm raised, cleared, latched and acknowledged on the virtual clock, a reload,
and the lab's hook (its rate limit, and a hook that hangs).

The rows fed to the board are made here, on a virtual time axis: 80 ms apart, T2 at its setpoint with a
cooler line and noise, T5 with the cooler's 0.12 K oscillation, unless a test changes one of them.
"""

import math
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest

from cryod.alarms.board import AlarmBoard
from cryod.alarms.latch import Transition
from cryod.alarms.settings import (AlarmHook, AlarmsConfig, CoolerLineLostAlarm, DeviationAlarm, HeaterNearTopAlarm,
                                   PtcStageWarmAlarm, StabilityAlarm)
from cryod.config import load_config
from cryod.service.alarm_hook import AlarmHookRunner, HookSchedule, run_hook
from drivers.clock import VirtualClock
from cryod.yaml_source import FileFormatError
from tests.conftest import CONFIG

PERIOD_S = 0.08
COOLER_RAD_S = 10.83
HEATER_TOP_W = 0.5


class Cryostat:
    """Rows of a regulated flange on a virtual time axis, fed to a board; the changes it made, with their row."""

    def __init__(self, alarms: AlarmsConfig, seed: int = 1):
        self.board = AlarmBoard(alarms, HEATER_TOP_W, COOLER_RAD_S, PERIOD_S)
        self.time_s = 0.0
        self.random = np.random.default_rng(seed)
        self.changes: list[Transition] = []
        self.state, self.setpoint_K, self.offset_K, self.noise_K = "closed", 5.0, 0.0, 20e-6
        self.T5_amplitude_K, self.T5_mean_K, self.heater_w = 0.12, 3.4, 0.11

    def run(self, duration_s: float) -> list[Transition]:
        """Rows for ``duration_s``; the changes they made."""
        made = []
        for _ in range(int(round(duration_s / PERIOD_S))):
            self.time_s += PERIOD_S
            t = self.time_s
            flange = (self.setpoint_K or 5.0) + self.offset_K + 0.4e-3 * math.sin(COOLER_RAD_S * t) \
                + self.noise_K * self.random.standard_normal()
            stage = (self.T5_mean_K + self.T5_amplitude_K * math.sin(COOLER_RAD_S * t)
                     + 3e-4 * self.random.standard_normal())
            made += self.board.take(t, self.state, flange, stage, self.heater_w, self.setpoint_K)
        self.changes += made
        return made

    def kinds(self, changes=None) -> list[tuple[str, str]]:
        return [(change.name, change.kind) for change in (self.changes if changes is None else changes)]

    def state_of(self, name: str) -> str:
        return next(alarm["state"] for alarm in self.board.alarms() if alarm["name"] == name)


# -- settings -------------------------------------------------------------------------------------
def with_alarms(tmp_path, text: str):
    source = (CONFIG / "cryod.yaml").read_text().replace("calibration: calibration/",
                                                          f"calibration: {CONFIG}/calibration/")
    source = re.sub(r"(?m)^alarms: null.*$", "", source)
    path = tmp_path / "cryod.yaml"
    path.write_text(source + "\n" + text)
    return path, source + "\n" + text


def test_the_example_has_alarms_off_and_its_commented_block_is_a_valid_section(tmp_path):
    assert load_config(CONFIG / "cryod.yaml").alarms.names == ()
    text = (CONFIG / "cryod.yaml").read_text()
    block = text[text.index("\n# alarms:") + 1:text.index("\nsimulation:")]
    section = "\n".join(line.split("#", 2)[1][1:] if line.startswith("#") else "" for line in block.splitlines())
    section = section.replace("/usr/local/bin/lab-alarm", sys.executable)
    config = load_config(with_alarms(tmp_path, section)[0])
    assert config.alarms.names == ("deviation", "stability", "ptc_stage_warm", "heater_near_top", "cooler_line_lost")
    assert config.alarms.deviation == DeviationAlarm(threshold_K=1e-4, window_s=10, delay_s=60)
    assert config.alarms.cooler_line_lost.latching and not config.alarms.stability.latching
    assert config.alarms.hook == AlarmHook((sys.executable, "--cryostat", "flange-A"), 10, 60)


def test_defaults_of_each_alarm(tmp_path):
    config = load_config(with_alarms(tmp_path, "alarms:\n  heater_near_top: {}\n  cooler_line_lost: {}\n"
                                               "  stability: {threshold_K: 1.0e-3}\n"
                                               "  hook: {command: 'sh -c \"exit 0\"'}\n")[0])
    assert config.alarms.heater_near_top == HeaterNearTopAlarm(fraction=0.95, delay_s=300.0)
    assert config.alarms.cooler_line_lost == CoolerLineLostAlarm(min_amplitude_K=0.03, delay_s=10.0, latching=True)
    assert config.alarms.stability == StabilityAlarm(threshold_K=1e-3, window_s=60.0, delay_s=0.0)
    assert config.alarms.hook.command == ("sh", "-c", "exit 0")


@pytest.mark.parametrize("text, key, reason", [
    ("alarms:\n  deviation: {window_s: 10}\n", "alarms.deviation.threshold_K", "missing required key"),
    ("alarms:\n  deviation: {threshold_K: 1.0e-4, windw_s: 10}\n", "alarms.deviation.windw_s", "unknown key"),
    ("alarms:\n  deviaton: {threshold_K: 1.0e-4}\n", "alarms.deviaton", "unknown key"),
    ("alarms:\n  stability: {threshold_K: 1.0e-4, deadband_K: 2.0e-4}\n", "alarms.stability.deadband_K",
     "could never clear"),
    ("alarms:\n  ptc_stage_warm: {threshold_K: 15}\n", "alarms.ptc_stage_warm.threshold_K",
     "not below safety.ptc_stage_max_K"),
    ("alarms:\n  heater_near_top: {fraction: 1.5}\n", "alarms.heater_near_top.fraction", "at most 1"),
    ("alarms:\n  deviation: {threshold_K: 1.0e-4, window_s: 7200}\n", "alarms.deviation.window_s", "at most 3600"),
    ("alarms:\n  cooler_line_lost: {latching: maybe}\n", "alarms.cooler_line_lost.latching", "true or false"),
    ("alarms:\n  hook: {command: no-such-program-here}\n", "alarms.hook.command", "not found on PATH"),
    ("alarms:\n  hook: {command: bin/notify}\n", "alarms.hook.command", "absolute path"),
    ("alarms:\n  hook: {command: /etc}\n", "alarms.hook.command", "not an executable file"),
    ("alarms:\n  hook: {command: []}\n", "alarms.hook.command", "must be a list of text"),
    ("alarms:\n  hook: {command: 'x \"unclosed'}\n", "alarms.hook.command", "cannot be split"),
])
def test_errors_name_file_line_and_key(tmp_path, text, key, reason):
    path, full = with_alarms(tmp_path, text)
    with pytest.raises(FileFormatError) as caught:
        load_config(path)
    message = str(caught.value)
    assert f"{path}:" in message and key in message and reason in message, message
    line = int(message.split(f"{path}:")[1].split(":")[0])
    *_, parent, name = ["", *key.split(".")]
    assert name in full.splitlines()[line - 1] or (reason == "missing required key"
                                                   and parent in full.splitlines()[line - 1]), (line, message)


def test_the_alarms_section_reloads_without_a_restart(tmp_path):
    before = load_config(with_alarms(tmp_path, "alarms: null\n")[0])
    after = load_config(with_alarms(tmp_path, "alarms:\n  stability: {threshold_K: 1.0e-3}\n")[0])
    assert before.restart_needed_for(after) == []


# -- each alarm on the virtual clock ----------------------------------------------------------------
def test_deviation_is_armed_at_the_setpoint_raised_after_its_delay_and_cleared():
    cryostat = Cryostat(AlarmsConfig(deviation=DeviationAlarm(threshold_K=100e-6, window_s=10, delay_s=20,
                                                              deadband_K=20e-6)))
    cryostat.offset_K = 500e-6                      # arriving at the setpoint: not armed, never raised
    assert cryostat.run(60) == []
    assert "settling" in cryostat.board.alarms()[0]["message"]
    cryostat.offset_K = 0.0
    assert cryostat.run(15) == []                   # armed
    cryostat.offset_K = -300e-6
    raised = cryostat.run(40)
    assert cryostat.kinds(raised) == [("deviation", "raised")]
    # the window (10 s) must see the offset first, then it holds for the delay (20 s)
    assert 75 + 20 <= raised[0].time_s <= 75 + 10 + 20 + 1.1
    assert re.search(r"averaged over 10 s -(29|30)\d\.\d µK from the setpoint 5.0000 K", raised[0].message)
    assert raised[0].value == pytest.approx(-300e-6, abs=20e-6)
    cryostat.offset_K = -90e-6                      # inside the threshold, not past the deadband: stands
    assert cryostat.run(20) == [] and cryostat.state_of("deviation") == "raised"
    cryostat.offset_K = 0.0
    assert cryostat.kinds(cryostat.run(12)) == [("deviation", "cleared")]


def test_deviation_is_not_raised_by_a_new_setpoint_or_outside_regulation():
    cryostat = Cryostat(AlarmsConfig(deviation=DeviationAlarm(threshold_K=100e-6, window_s=10, delay_s=5)))
    cryostat.run(30)                                # armed at 5 K
    cryostat.setpoint_K, cryostat.offset_K = 5.2, 0.05   # a new setpoint, T2 on its way: disarmed
    assert cryostat.run(60) == []
    cryostat.state = "manual"                       # open loop: not regulating
    assert cryostat.run(30) == []
    cryostat.state, cryostat.offset_K = "closed", 0.0
    cryostat.run(30)
    cryostat.offset_K = 1e-3
    assert cryostat.kinds(cryostat.run(30)) == [("deviation", "raised")]
    cryostat.state = "off"                          # leaving regulation clears it
    assert cryostat.kinds(cryostat.run(2)) == [("deviation", "cleared")]


def test_stability_raised_by_noise_and_cleared_when_it_goes():
    cryostat = Cryostat(AlarmsConfig(stability=StabilityAlarm(threshold_K=1e-3, window_s=20, delay_s=0)))
    assert cryostat.run(40) == []                   # the line (0.4 mK amplitude) leaves 0.28 mK rms
    cryostat.noise_K = 3e-3
    raised = cryostat.run(20)
    assert cryostat.kinds(raised) == [("stability", "raised")]
    assert raised[0].value > 1e-3 and "standard deviation over 20 s" in raised[0].message
    cryostat.noise_K = 20e-6
    cleared = cryostat.run(30)
    assert cryostat.kinds(cleared) == [("stability", "cleared")]
    assert cleared[0].time_s - cryostat.changes[0].time_s >= 20 - 1.1      # once the noisy readings left the window


def test_ptc_stage_warm_with_its_deadband_and_delay():
    cryostat = Cryostat(AlarmsConfig(ptc_stage_warm=PtcStageWarmAlarm(threshold_K=4.0, delay_s=3, deadband_K=0.2)))
    cryostat.T5_mean_K, cryostat.T5_amplitude_K = 4.1, 0.0
    raised = cryostat.run(5)
    assert cryostat.kinds(raised) == [("ptc_stage_warm", "raised")] and raised[0].time_s == pytest.approx(0.08 + 3.04)
    cryostat.T5_mean_K = 3.9                        # below the threshold, in the deadband
    assert cryostat.run(5) == []
    cryostat.T5_mean_K = 3.7
    assert cryostat.kinds(cryostat.run(1)) == [("ptc_stage_warm", "cleared")]
    cryostat.T5_mean_K = 4.1                        # a blip shorter than the delay raises nothing
    cryostat.run(2)
    cryostat.T5_mean_K = 3.5
    assert cryostat.run(5) == []


def test_heater_near_top_while_regulating_only():
    cryostat = Cryostat(AlarmsConfig(heater_near_top=HeaterNearTopAlarm(fraction=0.9, delay_s=30)))
    cryostat.heater_w = HEATER_TOP_W
    cryostat.state = "manual"                       # the operator's own choice: no alarm
    assert cryostat.run(60) == []
    cryostat.state = "closed-limited"
    raised = cryostat.run(50)
    assert cryostat.kinds(raised) == [("heater_near_top", "raised")]
    assert "100.0 % of its top R I_max^2 = 500.0 mW" in raised[0].message
    cryostat.state, cryostat.heater_w = "closed", 0.3
    assert cryostat.kinds(cryostat.run(12)) == [("heater_near_top", "cleared")]


def test_cooler_line_lost_latches_until_acknowledged():
    cryostat = Cryostat(AlarmsConfig(cooler_line_lost=CoolerLineLostAlarm(min_amplitude_K=0.03, delay_s=10)))
    assert cryostat.run(60) == []                   # locked within the delay
    assert re.fullmatch(r"cooler line on T5 1(19|20)\.\d mK, locked at 1\.72\d\d Hz",
                        cryostat.board.alarms()[0]["message"])
    cryostat.T5_amplitude_K = 0.0                   # the cooler stops
    raised = cryostat.run(20)
    assert cryostat.kinds(raised) == [("cooler_line_lost", "raised")]
    assert "below 30 mK" in raised[0].message and raised[0].time_s - 60 < 16
    cryostat.T5_amplitude_K = 0.12                  # it runs again: the alarm waits for someone to see it
    latched = cryostat.run(30)
    assert cryostat.kinds(latched) == [("cooler_line_lost", "latched")]
    assert cryostat.state_of("cooler_line_lost") == "latched"
    assert cryostat.board.raised()[0]["raised_message"].startswith("cooler line on T5 lost")
    acknowledged = cryostat.board.acknowledge("cooler_line_lost", cryostat.time_s, "uid 1000 (alice), pid 7")
    assert cryostat.kinds(acknowledged) == [("cooler_line_lost", "cleared")]
    assert "acknowledged by uid 1000 (alice)" in acknowledged[0].message
    assert cryostat.board.raised() == []


def test_an_acknowledged_alarm_clears_with_its_condition_and_acknowledgements_that_make_no_sense_are_refused():
    cryostat = Cryostat(AlarmsConfig(ptc_stage_warm=PtcStageWarmAlarm(threshold_K=4.0, delay_s=0, latching=True),
                                     stability=StabilityAlarm(threshold_K=1e-3)))
    with pytest.raises(ValueError, match="ptc_stage_warm is not raised"):
        cryostat.board.acknowledge("ptc_stage_warm", 0.0)
    with pytest.raises(ValueError, match="no alarm is raised"):
        cryostat.board.acknowledge("all", 0.0)
    with pytest.raises(ValueError, match="no alarm 'deviation' is on; alarms on: stability, ptc_stage_warm"):
        cryostat.board.acknowledge("deviation", 0.0)
    cryostat.T5_mean_K, cryostat.T5_amplitude_K = 4.2, 0.0
    cryostat.run(1)
    assert cryostat.kinds(cryostat.board.acknowledge("all", cryostat.time_s)) == [("ptc_stage_warm", "acknowledged")]
    with pytest.raises(ValueError, match="acknowledged already"):
        cryostat.board.acknowledge("ptc_stage_warm", cryostat.time_s)
    assert cryostat.board.raised()[0]["acknowledged"] is True
    cryostat.T5_mean_K = 3.5                        # acknowledged while it stood: no latch
    assert cryostat.kinds(cryostat.run(1)) == [("ptc_stage_warm", "cleared")]


def test_a_reload_keeps_what_stands_applies_new_thresholds_and_clears_alarms_switched_off():
    warm = PtcStageWarmAlarm(threshold_K=4.0, delay_s=0)
    cryostat = Cryostat(AlarmsConfig(ptc_stage_warm=warm, stability=StabilityAlarm(threshold_K=1e-3)))
    cryostat.T5_mean_K, cryostat.T5_amplitude_K = 4.2, 0.0
    cryostat.run(70)                                # stability armed
    cryostat.noise_K = 3e-3
    cryostat.run(10)
    assert sorted(cryostat.kinds()) == [("ptc_stage_warm", "raised"), ("stability", "raised")]
    changes = cryostat.board.reconfigure(AlarmsConfig(ptc_stage_warm=warm), cryostat.time_s)
    assert cryostat.kinds(changes) == [("stability", "cleared")]
    assert "switched off by the configuration" in changes[0].message
    assert cryostat.run(5) == [] and cryostat.state_of("ptc_stage_warm") == "raised"   # kept, not raised again
    cryostat.board.reconfigure(AlarmsConfig(ptc_stage_warm=PtcStageWarmAlarm(threshold_K=4.5, delay_s=0)),
                               cryostat.time_s)
    assert cryostat.kinds(cryostat.run(1)) == [("ptc_stage_warm", "cleared")]             # the new threshold


# -- the hook ------------------------------------------------------------------------------------------
def change(kind="raised", name="deviation", time_s=0.0):
    return Transition(name, kind, time_s, f"T2 {kind}", np.float64(1e-4))      # as numpy's mean gives it


def test_the_hook_runs_at_most_once_per_interval_for_each_alarm_with_the_latest_change():
    clock = VirtualClock()
    runs = []
    runner = AlarmHookRunner(clock, "flange-A", AlarmHook(("notify",), 5.0, 60.0),
                             runner=lambda hook, details: runs.append((clock.now(), details)))
    runner.start()
    try:
        def wait_for(count):
            deadline = time.monotonic() + 10
            while len(runs) < count:
                assert time.monotonic() < deadline, runs
                time.sleep(0.01)

        runner.offer(change("raised"))
        runner.offer(change("raised", name="stability"))
        wait_for(2)
        for kind in ("cleared", "raised", "cleared"):     # within the minute: folded into one run
            clock.advance(5.0)
            runner.offer(change(kind, time_s=clock.now()))
        time.sleep(0.5)                                   # wall time passes, the daemon's clock does not
        assert len(runs) == 2
        clock.advance(45.0)                               # 60 s after the first run
        wait_for(3)
        at_s, details = runs[2]
        assert at_s == pytest.approx(60.0)
        assert (details["CRYOD_ALARM"], details["CRYOD_ALARM_EVENT"], details["CRYOD_ALARM_SKIPPED"]) == \
            ("deviation", "cleared", "2")
        assert details["CRYOD_CRYOSTAT"] == "flange-A" and details["CRYOD_ALARM_VALUE"] == "0.0001"
    finally:
        runner.stop()
    assert len(runs) == 3


def test_the_schedule_folds_changes_per_alarm():
    schedule = HookSchedule(min_interval_s=10.0)
    schedule.offer(change("raised", "deviation"))
    schedule.offer(change("raised", "stability"))
    assert [notice.transition.name for notice in schedule.due(0.0)] == ["deviation", "stability"]
    schedule.offer(change("cleared", "deviation"))
    assert schedule.due(9.9) == [] and schedule.next_due_s() == 10.0
    assert [(n.transition.kind, n.skipped) for n in schedule.due(10.0)] == [("cleared", 0)]
    assert schedule.next_due_s() == math.inf


def test_a_hook_gets_the_details_in_its_environment_and_as_json(tmp_path):
    out = tmp_path / "out.txt"
    script = tmp_path / "hook.sh"
    script.write_text(f'#!/bin/sh\necho "$CRYOD_ALARM $CRYOD_ALARM_EVENT" > {out}\ncat >> {out}\n')
    script.chmod(0o755)
    from cryod.service.alarm_hook import HookNotice, hook_details

    assert run_hook(AlarmHook((str(script),)), hook_details(HookNotice(change("latched")), "A")) is None
    first, payload = out.read_text().split("\n", 1)
    assert first == "deviation latched"
    import json

    assert json.loads(payload)["alarm_message"] == "T2 latched"
    failing = AlarmHook(("/bin/sh", "-c", "echo no mail server >&2; exit 3"))
    assert run_hook(failing, {}) == "exit 3: no mail server"


@pytest.mark.system
def test_a_hook_that_hangs_is_killed_and_never_holds_up_the_changes(tmp_path, caplog):
    marker = tmp_path / "child.pid"
    hanging = AlarmHook(("/bin/sh", "-c", f"sleep 60 & echo $! > {marker}; wait"), timeout_s=0.5,
                        min_interval_s=0.0)
    clock = VirtualClock()
    runner = AlarmHookRunner(clock, "", hanging)
    runner.start()
    try:
        started = time.monotonic()
        for index in range(1000):                  # the loop's side: a deque append each
            runner.offer(change("raised", time_s=float(index)))
        assert time.monotonic() - started < 0.5
        deadline = time.monotonic() + 20
        while runner.failures < 1:
            assert time.monotonic() < deadline
            time.sleep(0.02)
    finally:
        runner.stop()
    assert "still running after 0.5 s (alarms.hook.timeout_s): killed" in caplog.text
    child = int(marker.read_text())
    deadline = time.monotonic() + 5
    while _alive(child):                            # its whole process group went with it
        assert time.monotonic() < deadline, "the hook's child outlived it"
        time.sleep(0.02)


HOOK_IN_A_CHILD = """
import json, os, sys, time
from cryod.alarms.settings import AlarmHook
from cryod.service.alarm_hook import run_hook
from cryod.service.process_tree import become_subreaper

become_subreaper()
command, timeout_s = json.loads(sys.argv[1])
started = time.monotonic()
problem = run_hook(AlarmHook(tuple(command), timeout_s=timeout_s), {})
wall_s = time.monotonic() - started
with open("/proc/self/status") as status:
    peak_kB = int(next(line.split()[1] for line in status if line.startswith("VmHWM")))
print(json.dumps({"problem": problem, "wall_s": wall_s, "peak_MB": peak_kB / 1e3}))
"""


def hook_in_a_child(command: list[str], timeout_s: float) -> dict:
    """run_hook in a fresh Python process, as the process that runs hooks does it (its own subreaper): the problem,
    the wall time of the run and the process' peak resident memory."""
    import json

    done = subprocess.run([sys.executable, "-c", HOOK_IN_A_CHILD, json.dumps([command, timeout_s])],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.system
def test_a_hook_that_writes_without_end_costs_its_runner_a_bounded_memory(tmp_path):
    """200 MB of output (the trial's 500 MB in the slow suite): read and dropped as it comes, the last 64 KiB held;
    the runner's peak stays within a few MB of a run of a quiet hook."""
    quiet = hook_in_a_child(["/bin/true"], 10.0)
    flood = hook_in_a_child(["/bin/sh", "-c", "head -c 200000000 /dev/zero; exit 2"], 30.0)
    assert flood["problem"].startswith("exit 2")
    assert flood["peak_MB"] - quiet["peak_MB"] < 5.0, (quiet, flood)


@pytest.mark.system
def test_a_hook_that_leaves_a_child_in_a_session_of_its_own_is_ended_with_it_at_its_timeout(tmp_path):
    """``setsid sleep & exit 0``: the sleep holds the hook's output open from a new session. The run ends at the
    timeout (not never), says why, and the sleep is killed with it."""
    marker = tmp_path / "sleep.pid"
    result = hook_in_a_child(["/bin/sh", "-c", f"setsid sleep 100003 & echo $! > {marker}; exit 0"], 1.0)
    assert 1.0 <= result["wall_s"] < 4.0
    assert result["problem"].startswith("exited, but left 1 process(es) running that held its output open")
    child = int(marker.read_text())
    deadline = time.monotonic() + 5
    while _alive(child):
        assert time.monotonic() < deadline, "the hook's child in a session of its own outlived it"
        time.sleep(0.02)


def test_a_hook_that_cannot_run_is_said_at_once_in_the_journal_and_the_status(tmp_path, caplog):
    runner = AlarmHookRunner(VirtualClock(), "", AlarmHook((str(tmp_path / "no-such-hook"),)))
    runner.start()
    try:
        assert "no-such-hook cannot be run" in caplog.text
        assert "cannot be run" in runner.status()["problem"]
    finally:
        runner.stop()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    state = subprocess.run(["ps", "-o", "stat=", "-p", str(pid)], capture_output=True, text=True).stdout.strip()
    return bool(state) and not state.startswith("Z")


# -- in the daemon: record, journal, status, ctl, Python API, metrics, reload --------------------------
def while_ticking(daemon, function):
    """``function()`` on a thread of its own while the gated loop runs ticks; its result."""
    import threading

    result = {}

    def call():
        try:
            result["value"] = function()
        except BaseException as error:          # handed to the test
            result["error"] = error

    thread = threading.Thread(target=call)
    thread.start()
    while thread.is_alive():
        daemon.gate.run_ticks(1)
        thread.join(0.005)
    if "error" in result:
        raise result["error"]
    return result["value"]


def test_an_alarm_in_the_daemon_is_said_everywhere_and_acknowledged_through_every_path(tmp_path, caplog, capsys):
    import dataclasses
    import logging

    from prometheus_client.exposition import generate_latest
    from prometheus_client import CollectorRegistry

    from cryod.cli import main
    from cryod.client import CommandRefused, DaemonClient
    from cryod.service.control_socket import send_command
    from cryod.interfaces.metrics import CryodCollector
    from tests.gated_daemon import GatedDaemon

    warm = PtcStageWarmAlarm(threshold_K=3.0, delay_s=1.0, latching=True)      # the simulated T5 is above it
    alarms = AlarmsConfig(ptc_stage_warm=warm, deviation=DeviationAlarm(threshold_K=1e-3))
    caplog.set_level(logging.INFO, logger="cryod")
    with GatedDaemon(tmp_path, sections={"alarms": alarms}) as daemon:
        daemon.gate.run_ticks(20)
        client = DaemonClient(daemon.socket_path)
        status = client.status()
        assert [alarm["name"] for alarm in status["alarms"]] == ["ptc_stage_warm"]
        assert status["alarms"][0]["state"] == "raised" and status["alarms"][0]["raised_message"].startswith("T5 3.")
        assert [(alarm["name"], alarm["state"]) for alarm in client.alarms()] == \
            [("deviation", "clear"), ("ptc_stage_warm", "raised")]
        registry = CollectorRegistry()
        registry.register(CryodCollector(daemon.daemon.live_view, "A", daemon.daemon.alarms.states))
        metrics = generate_latest(registry).decode()
        assert 'cryod_alarm{name="ptc_stage_warm"} 1.0' in metrics and 'cryod_alarm{name="deviation"} 0.0' in metrics

        assert main(["ctl", "--socket", str(daemon.socket_path), "alarms"]) == 0
        listed = capsys.readouterr().out.splitlines()
        assert listed[0].startswith("deviation: ") and listed[1].startswith("ptc_stage_warm: raised since ")
        assert main(["ctl", "--socket", str(daemon.socket_path), "status"]) == 0
        printed = capsys.readouterr().out
        assert "alarms:\n  ptc_stage_warm: raised since" in printed

        # the condition ends by a reload with a higher threshold: latched, then acknowledged
        new = dataclasses.replace(daemon.config, alarms=dataclasses.replace(
            alarms, ptc_stage_warm=dataclasses.replace(warm, threshold_K=14.0)))
        daemon.daemon.reload_config = lambda: new
        assert while_ticking(daemon, lambda: daemon.daemon.reload("test")).ok
        daemon.gate.run_ticks(2)
        assert client.status()["alarms"][0]["state"] == "latched"
        with pytest.raises(CommandRefused, match="deviation is not raised"):
            while_ticking(daemon, lambda: client.acknowledge_alarm("deviation"))
        reply = while_ticking(daemon, lambda: send_command(daemon.socket_path, "alarms ack ptc_stage_warm"))
        assert reply["ok"] and reply["message"].startswith("ptc_stage_warm cleared: acknowledged by uid ")
        assert [alarm["state"] for alarm in reply["alarms"]] == ["clear", "clear"] and reply["status"]["alarms"] == []
        refused = send_command(daemon.socket_path, "alarms ack nothing")
        assert not refused["ok"] and "give one of deviation, stability" in refused["message"]
        daemon.gate.run_ticks(2)
        record_path = daemon.daemon.datalog.paths[-1]
    record = record_path.read_text().splitlines()
    events = [line for line in record if line.startswith("# event: alarm: ")]
    assert [line.split(":")[2].strip() for line in events] == \
        ["ptc_stage_warm raised", "ptc_stage_warm latched", "ptc_stage_warm cleared"]
    raised_at = record.index(events[0])
    row_before = record[raised_at - 1]                  # right after the row that raised it
    assert not row_before.startswith("#") and float(row_before.split(",")[0]) >= 1.0
    warnings = [r.getMessage() for r in caplog.records if r.name == "cryod.alarms" and r.levelno == logging.WARNING]
    assert [message.split(":")[0] for message in warnings] == \
        ["alarm ptc_stage_warm raised", "alarm ptc_stage_warm latched", "alarm ptc_stage_warm cleared"]


@pytest.mark.system
def test_the_web_page_shows_the_alarms_the_status_carries(tmp_path, browser):
    from cryod.config import WebConfig
    from tests.gated_daemon import GatedDaemon
    from tests.headless_browser import port_of, wait_until

    alarms = AlarmsConfig(ptc_stage_warm=PtcStageWarmAlarm(threshold_K=3.0, delay_s=0.0),
                          stability=StabilityAlarm(threshold_K=1e-3))
    with GatedDaemon(tmp_path, sections={"web": WebConfig("127.0.0.1:0"), "alarms": alarms}) as daemon:
        daemon.gate.run_ticks(20)
        browser.get(f"http://127.0.0.1:{port_of(daemon)}/")
        wait_until(lambda: browser.find_element("id", "connection").text == "live", "connect")
        daemon.gate.run_ticks(10)
        raised = daemon.daemon.alarms.raised()
        assert [alarm["name"] for alarm in raised] == ["ptc_stage_warm"]

        def shown_alarms():           # read in one go: the page renders the list again at each push
            return browser.execute_script(
                'return [...document.querySelectorAll("#alarms li")].map((item) => [item.dataset.alarm, '
                'item.textContent]);')

        wait_until(lambda: shown_alarms() and shown_alarms()[0][0] == "ptc_stage_warm", "show the alarm")
        name, text = shown_alarms()[0]
        assert text.startswith("ptc_stage_warm raised: T5 3.") and "(threshold 3 K)" in text
        assert browser.find_element("id", "alarms").get_attribute("hidden") is None
        def events():
            return browser.execute_script('return [...document.querySelectorAll("#events li")].map((item) => '
                                          'item.textContent);')

        def listed():                 # an event reaches the page with a frame; one taken after the last frame
            if any("alarm: ptc_stage_warm raised: T5 3." in event for event in events()):
                return True
            daemon.gate.run_ticks(1)  # waits for the next, which the held loop makes only when let tick
            return False

        wait_until(listed, "list the alarm's event")


def test_an_error_in_the_alarms_never_reaches_the_loop(caplog):
    from cryod.records.columns import Event, Row
    from cryod.service.alarms import AlarmMonitor
    from cryod.service.commands import Command

    monitor = AlarmMonitor(AlarmsConfig(ptc_stage_warm=PtcStageWarmAlarm(threshold_K=4.0)), HEATER_TOP_W,
                           COOLER_RAD_S, PERIOD_S)
    emitted = []
    monitor.attach(emitted.append)

    def broken(*arguments):
        raise ZeroDivisionError("a bug")

    monitor.board.take = broken
    row = Row(time_s=1.0, lateness_ms=0.1, state="closed", T2_K=5.0, T5_K=4.5, heater_W=0.1, setpoint_K=5.0)
    monitor(row)                                    # no exception: the loop goes on
    monitor(row)
    assert emitted == [Event("alarm", "the alarms stopped on an error (see the journal); regulation goes on "
                                      "without them")]
    assert "the alarms stopped on an error" in caplog.text and "ZeroDivisionError" in caplog.text
    command = monitor.submit(Command("alarms", ("ack", "all")))
    assert command.done.is_set() and not command.ok and "stopped on an error" in command.message


def test_the_status_line_names_the_alarms_raised():
    from cryod.service.live_view import LiveView
    from cryod.service.status_line import format_status

    view = LiveView(PERIOD_S, COOLER_RAD_S)
    assert view.snapshot()["alarms"] == []
    view.attach_alarms(lambda: ["deviation", "cooler_line_lost"])
    assert format_status(view.snapshot()).endswith("ALARM deviation, cooler_line_lost (cryod ctl alarms)")
