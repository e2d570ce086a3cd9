"""Commissioning: the identification experiment through the daemon on the simulated cryostat (virtual clock),
finished, interrupted and stopped by a fault; then the fit, the model file, the figures and the report."""

import io
import json
import math
import os
import signal

import numpy as np
import pytest

from cryod import cli
from cryod.cli.acquire import INTERRUPTED_EXIT, ProgressDisplay, acquire
from cryod.identification.experiment import ExperimentPlan, ExperimentRunner, Progress, SettleJudge
from cryod.model import load_model
from cryod.records.columns import Row
from cryod.records.record import read_record
from drivers.clock import VirtualClock
from cryod.service.simulation import SimulatedInstrumentsOpener
from tests.example_config import simulated_config


class RowCounter:
    """A row tap that runs ``action(opener)`` once, at a given row (time s of the record)."""

    def __init__(self, opener, at_s, action):
        self.opener, self.at_s, self.action = opener, at_s, action
        self.rows = []

    def __call__(self, item):
        if isinstance(item, Row):
            self.rows.append(item)
            if self.action is not None and item.time_s >= self.at_s:
                action, self.action = self.action, None
                action(self.opener)


def events(path):
    return [line for line in path.read_text().splitlines() if line.startswith("# event:")]


# -- the experiment's logic, without the daemon --------------------------------------------------
def test_plan_refuses_what_the_heater_cannot_do():
    ExperimentPlan(step_power_w=0.01, modulation_amplitude_w=0.005).check(0.5)
    with pytest.raises(ValueError, match="above the heater's R \\* I_max\\^2 = 0.25 W.*--step-power"):
        ExperimentPlan(step_power_w=0.2, base_power_w=0.1).check(0.25)
    with pytest.raises(ValueError, match="modulation 0.01 \\+- 0.02 W leaves the heater's range"):
        ExperimentPlan(step_power_w=0.01, modulation_amplitude_w=0.02).check(0.5)
    with pytest.raises(ValueError, match="--max-settle"):
        ExperimentPlan(max_settle_s=100.0, min_settle_s=50.0).check(0.5)
    assert ExperimentPlan(base_power_w=0.05, modulation_amplitude_w=0.001).phases == \
        ("approach", "line", "step", "modulation")


def test_settled_by_the_stated_criterion_at_the_expected_time():
    """A 165 s exponential of 60 mK from 4.23 K: the straight line over the last 120 s has the slope at the
    window's middle, so T2 moves 0.5 % of its change per window when
    60 mK x 120/165 x exp(-(t - 60)/165) = 0.005 x 60 mK, t = 60 + 165 ln(120 / 0.825) = 882 s."""
    plan = ExperimentPlan()
    judge = SettleJudge(plan, expected_s=825.0, reference_K=4.23)
    settled_at, estimates = None, {}
    for k in range(int(2000 / 0.08)):
        t = k * 0.08
        judge.add(t, 4.23 + 0.06 * (1 - math.exp(-t / 165.0)) + 1.7e-3 * math.sin(10.83 * t))
        if k % 12 == 0 and settled_at is None:
            if judge.judge(t):
                settled_at = t
            elif t in (400.08, 600.0):
                estimates[t] = judge.time_left_s(t)
    assert settled_at == pytest.approx(60.0 + 165.0 * math.log(120.0 / 0.825), abs=2.0)
    assert estimates[600.0] == pytest.approx(282.0, rel=0.1)        # from the drift's decay, not the guess
    floor = SettleJudge(plan, expected_s=825.0)                    # a flat flange is settled after min_settle_s
    for k in range(int(400 / 0.08)):
        floor.add(k * 0.08, 4.23)
    assert not floor.judge(299.0) and floor.judge(300.0)


def test_runner_phases_commands_and_a_fault_stop():
    commands, stops, notes = [], [], []
    plan = ExperimentPlan(line_hold_s=20.0, min_settle_s=0.0, max_settle_s=240.0, settle_window_s=20.0,
                          modulation_amplitude_w=0.002, modulation_s=10.0)
    runner = ExperimentRunner(plan, lambda name, value: commands.append((name, value)), stops.append, notes.append)
    runner(Row(time_s=0.08, lateness_ms=0.0, T2_K=4.23, state="holding"))
    assert commands == [] and runner.phase is None              # the plan waits for valid readings
    t = 0.16
    while runner.outcome is None and t < 400.0:
        runner(Row(time_s=t, lateness_ms=0.0, T2_K=4.23, heater_W=0.0, state="manual"))
        t += 0.08
    assert [name for name, _ in commands] == ["manual", "manual", "modulate"]
    assert commands[1][1] == 0.01 and commands[2][1].amplitude_w == 0.002
    assert [phase for phase, _, _ in runner.phase_log] == ["line", "step", "modulation"]
    assert runner.outcome == "finished" and stops == ["identification experiment finished"]
    faulty = ExperimentRunner(plan, lambda *a: None, stops.append, notes.append)
    faulty(Row(time_s=1.0, lateness_ms=0.0, T2_K=4.23, state="manual"))
    faulty(Row(time_s=1.08, lateness_ms=0.0, T2_K=math.nan, state="fault:sensor_overflow"))
    assert faulty.outcome == "fault" and faulty.fault == "sensor_overflow"
    assert stops[-1] == "identification experiment stopped by the fault sensor_overflow"


def test_progress_display_shows_phase_and_time_left_on_a_terminal():
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    progress = Progress(phase="step", phase_index=2, phase_count=3, elapsed_s=300.0, time_left_s=540.0,
                        flange_K=4.26, heater_w=0.01)
    assert ProgressDisplay.describe(progress) == "step (2/3) | T2 4.26000 K | heater 10.00 mW | ~9 min left"
    stream = Terminal()
    with ProgressDisplay(lambda: progress, stream=stream, interval_s=0.01):
        pass
    assert "step (2/3)" in stream.getvalue() and "~9 min left" in stream.getvalue()
    assert not ProgressDisplay(lambda: progress, stream=io.StringIO()).enabled     # off when not a terminal


# -- through the daemon, on the virtual clock -----------------------------------------------------
def test_acquire_simulate_end_to_end_writes_model_figures_and_report(tmp_path, capsys):
    out = tmp_path / "lab-model.yaml"
    report = tmp_path / "report"
    status = cli.main(["identify", "--acquire", "--simulate", "--out", str(out), "--data-dir", str(tmp_path / "data"),
                       "--socket", str(tmp_path / "c.sock"), "--seed", "7", "--bootstrap", "8", "--no-tune",
                       "--modulation-amplitude", "0.004", "--modulation-time", "60", "--report", str(report),
                       "--json"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    assert "experiment finished, heater at 0 W" in captured.err
    summary = json.loads(captured.out)
    assert summary["heater_to_thermometer_terms"] == 2 and summary["heater_to_ptc_stage_terms"] == 1
    assert summary["heater_to_thermometer_time_constants_s"] == pytest.approx([26.48, 165.41], rel=0.01)
    parameters = summary["parameters"]
    for name, truth in (("heater_to_thermometer.time_constant_s.1", 26.48),
                        ("heater_to_thermometer.time_constant_s.2", 165.41),
                        ("heater_to_ptc_stage.time_constant_s.1", 135.0),
                        ("heater_to_ptc_stage.gain_K_per_W.1", 2.77)):
        estimate = parameters[name]
        assert abs(estimate["value"] - truth) < 4.0 * estimate["standard_uncertainty"], name
        assert 0.0 < estimate["standard_uncertainty"] < 0.01 * truth
    model = load_model(out)
    assert model.uncertainty is not None and len(model.uncertainty.names) == 13
    record_path = tmp_path / "data" / os.listdir(tmp_path / "data")[0]
    record = read_record(record_path)
    heater = record.heater_w
    assert heater[0] == 0.0 and np.max(heater) == pytest.approx(0.014) and heater[-1] == pytest.approx(0.01, abs=0.004)
    lines = events(record_path)
    assert any("phase step settled after" in line for line in lines)
    assert lines[-1].startswith("# event: stop: stop_requested: identification experiment finished")
    assert "identify_settle_criterion" in record.metadata
    for name in ("fit_T2.png", "fit_T5.png", "fit_line.png", "terms.png", "report.md"):
        assert (report / name).stat().st_size > 1000, name
    text = (report / "report.md").read_text()
    assert "limit (best heater waveform)" in text and "central 95 %" in text
    assert "G2 G1 (heater to T2), term 2: time constant" in text
    # the model exists now: refused without --force, before anything is measured
    assert cli.main(["identify", "--acquire", "--simulate", "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err


def test_ctrl_c_keeps_the_record_and_leaves_the_heater_at_0_w(tmp_path, terminal_signals):
    opener = SimulatedInstrumentsOpener(load_model(), seed=5)
    interrupt = RowCounter(opener, 300.0, lambda _: os.kill(os.getpid(), signal.SIGINT))
    acquisition = acquire(simulated_config(tmp_path), ExperimentPlan(), opener, VirtualClock(), row_taps=[interrupt])
    assert acquisition.outcome == "interrupted" and acquisition.exit_code == INTERRUPTED_EXIT == 130
    assert "interrupted (SIGINT received) in phase step" in acquisition.message
    assert opener.bench.heater_supply.output_current_a == 0.0
    record = read_record(acquisition.record_paths[0])
    assert len(record) == pytest.approx(len(interrupt.rows), abs=2)         # every row read is in the file
    assert record.heater_w.max() == pytest.approx(0.01) and record.time_s[-1] == pytest.approx(300.0, abs=0.5)
    assert "SIGINT received" in events(acquisition.record_paths[0])[-1]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler      # the daemon gave Ctrl-C back


def test_a_fault_the_daemon_would_recover_from_still_ends_the_experiment(tmp_path):
    opener = SimulatedInstrumentsOpener(load_model(), seed=6)
    overflow = RowCounter(opener, 400.0, lambda o: o.bench.ptc_stage_dmm.inject_overflow(3))
    acquisition = acquire(simulated_config(tmp_path), ExperimentPlan(), opener, VirtualClock(),
                          row_taps=[overflow], install_signal_handlers=False)
    assert acquisition.outcome == "fault" and acquisition.exit_code == 4
    assert "sensor_overflow in phase step" in acquisition.message
    assert opener.bench.heater_supply.output_current_a == 0.0
    record = read_record(acquisition.record_paths[0])
    assert "fault:sensor_overflow" in [str(s) for s in record.columns["state"]]
    assert record.heater_w[-1] == 0.0
    assert any("identification stopped in phase step: fault sensor_overflow" in line
               for line in events(acquisition.record_paths[0]))


def test_acquire_refuses_a_step_beyond_the_heater_before_touching_anything(tmp_path, capsys):
    status = cli.main(["identify", "--acquire", "--simulate", "--out", str(tmp_path / "m.yaml"),
                       "--data-dir", str(tmp_path / "data"), "--socket", str(tmp_path / "c.sock"),
                       "--step-power", "0.6"])
    assert status == 2
    assert "above the heater's R * I_max^2 = 0.5 W" in capsys.readouterr().err
    assert not (tmp_path / "data").exists() and not (tmp_path / "m.yaml").exists()
