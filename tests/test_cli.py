"""The command line: help, errors a user can act on, and the --simulate --json contract."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from cryod.cli import main
from cryod.records.record import read_record
from tests.conftest import CONFIG, REPOSITORY
from tests.example_config import line_of, simulate_args

CONTRACT_KEYS = {"duration_s", "ticks", "overruns", "lateness_ms_p50", "lateness_ms_p99", "lateness_ms_max",
                 "wall_s", "ptc_line_amplitude_K", "rms_K", "mean_error_K", "lowfreq_rms_K", "log_path"}


def cryod(*arguments, timeout=120):
    return subprocess.run([sys.executable, "-m", "cryod.cli", *arguments], capture_output=True, text=True,
                          cwd=REPOSITORY, timeout=timeout)


@pytest.mark.parametrize("arguments, words", [
    (["--help"], ["--simulate", "run", "ctl", "--speed", "--sim-model", "--window"]),
    (["run", "--help"], ["--config", "--check"]),
    (["ctl", "--help"], ["setpoint", "heater-off", "--socket"]),
])
def test_help(arguments, words):
    result = cryod(*arguments)
    assert result.returncode == 0
    assert all(word in result.stdout for word in words)
    assert "RUN_CONFIG" not in result.stdout and "CTL_SOCKET" not in result.stdout      # metavars in the lab's words


def test_no_command_prints_usage_and_fails():
    result = cryod()
    assert result.returncode == 2 and "usage: cryod" in result.stderr


@pytest.mark.parametrize("arguments, message", [
    (["--simulate", "run"], "do not combine"),
    (["--simulate", "--speed", "0"], "must be > 0, got '0'"),
    (["--simulate", "--speed", "fast"], "a number > 0 or 'max'"),
    (["--simulate", "--speed", "max", "--setpoint", "50"], "--setpoint 50 K is outside"),
    (["--simulate", "--speed", "max", "--transport", "tcp"], "only the in-process transport"),
    (["--simulate", "--speed", "max", "--sim-model", "no/such/model.yaml"], "file not found"),
    (["simulate", "--speed", "max", "--setpoint", "50"], "--setpoint 50 K is outside"),      # the alias
    (["--simulate", "--speed", "max", "--setpoint", "1_5"], "expected a number, got '1_5'"),
    (["--duration", "5", "run"], "--duration: option(s) of the dry run"),
    (["--socket", "/tmp/x.sock", "--json", "ctl", "status"], "--json: option(s) of the dry run"),
])
def test_usage_errors_name_the_problem(arguments, message, capsys):
    """Each refused before anything starts, exit 2 with the problem named (in process: the exit code and the
    message are main's; the real process's exit code is checked once below)."""
    try:
        code = main(arguments)
    except SystemExit as stop:          # argparse's own refusals
        code = stop.code
    assert code == 2
    assert message in capsys.readouterr().err


@pytest.mark.system
def test_a_usage_error_is_exit_2_of_the_real_process():
    result = cryod("--simulate", "--speed", "max", "--setpoint", "50")
    assert result.returncode == 2
    assert "--setpoint 50 K is outside" in result.stderr


def test_ctl_without_daemon(tmp_path):
    result = cryod("ctl", "--socket", str(tmp_path / "nobody.sock"), "status")
    assert result.returncode == 3 and "no cryod daemon listening" in result.stderr
    result = cryod("--socket", str(tmp_path / "top.sock"), "ctl", "status")      # a top-level --socket is used
    assert result.returncode == 3 and "top.sock" in result.stderr


def test_ctl_finds_a_dry_run_without_options_and_says_where_it_looked(tmp_path, monkeypatch, capsys, runtime_dir):
    runtime = runtime_dir
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    monkeypatch.setattr("cryod.service.discovery.SERVICE_CONFIG", tmp_path / "absent.yaml")
    assert main(["ctl", "status"]) == 3
    error = capsys.readouterr().err
    assert f"{runtime}/cryod/simulate.sock (a cryod --simulate of this user)" in error and "--socket PATH" in error
    taps = []

    def ask_while_running(item):       # the loop thread asks through the socket, as a user beside it would
        if not taps and getattr(item, "state", "") == "closed":
            taps.append(main(["ctl", "status"]))
            taps.append(capsys.readouterr().out)

    from cryod.service import simulation
    original = simulation.WindowCollector.__call__
    monkeypatch.setattr(simulation.WindowCollector, "__call__", lambda self, item: (original(self, item),
                                                                                  ask_while_running(item)))
    assert main(["simulate", "--speed", "max", "--duration", "30", "--data-dir", str(tmp_path / "data")]) == 0
    assert taps[0] == 0
    lines = taps[1].splitlines()
    # the status of the tick before the first closed one: regulating, the heater still at its top or not
    assert {"state: closed", "state: closed-limited"} & set(lines)
    assert any(line.startswith("T2_K: ") and line.endswith(" K") for line in lines)
    assert any(line.startswith("heater_W: ") and line.endswith(" mW") for line in lines)


def test_a_per_user_directory_of_someone_else_is_refused(tmp_path, monkeypatch):
    from cryod.service.discovery import simulation_socket

    runtime = tmp_path / "runtime"
    (runtime / "cryod").mkdir(parents=True)
    (runtime / "cryod").chmod(0o777)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(runtime))
    with pytest.raises(PermissionError, match="not a private directory"):
        simulation_socket()


@pytest.mark.system
def test_run_check_validates_without_instruments(tmp_path, capsys):
    text = (CONFIG / "cryod.yaml").read_text().replace("calibration: calibration/", f"calibration: {CONFIG}/calibration/")
    lan = tmp_path / "lan.yaml"          # the instruments behind a LAN-to-GPIB gateway: no GPIB card binding needed
    lan.write_text(text.replace("GPIB0::16::INSTR", "TCPIP0::192.168.1.20::1234::SOCKET")
                   .replace("GPIB0::17::INSTR", "TCPIP0::192.168.1.21::1234::SOCKET")
                   .replace("GPIB0::12::INSTR", "TCPIP0::192.168.1.22::1234::SOCKET")
                   .replace("trigger: gpib-group", "trigger: sequential")       # no GPIB card to trigger on
                   .replace("/var/lib/cryod", str(tmp_path / "data"))
                   .replace("/run/cryod/control.sock", str(tmp_path / "control.sock")))
    code = main(["run", "--config", str(lan), "--check"])     # in process: test_run_check runs it as a process
    captured = capsys.readouterr()
    assert code == 0 and "valid" in captured.out, captured.err


def test_a_gpib_card_without_its_python_binding_is_an_installation_error_not_an_outage(capsys):
    """In process (the exit code and the message are main's; test_run_check runs ``cryod run`` and ``--check``
    as processes)."""
    import importlib.util

    if importlib.util.find_spec("gpib") or importlib.util.find_spec("gpib_ctypes"):
        pytest.skip("a GPIB binding is installed here")
    assert main(["run", "--config", str(CONFIG / "cryod.yaml"), "--check"]) == 2
    stderr = capsys.readouterr().err
    line = line_of((CONFIG / "cryod.yaml").read_text(), "GPIB0::16::INSTR")
    assert f"cryod.yaml:{line}: instruments.flange_dmm.resource: GPIB0::16::INSTR is on a GPIB card" in stderr
    assert "linux-gpib" in stderr
    assert "Traceback" not in stderr


def test_simulate_json_contract_and_log(tmp_path, capsys):
    code = main(simulate_args(tmp_path, "--duration", "600", "--window", "300", "--json", "--seed", "3",
                              "--no-feedforward"))
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert CONTRACT_KEYS <= set(summary)
    assert summary["ticks"] == 7500 and summary["duration_s"] == pytest.approx(600.0)
    assert summary["overruns"] == 0
    assert summary["window_s"] == pytest.approx(300.0, abs=0.2)
    assert 1.5e-3 < summary["ptc_line_amplitude_K"] < 2.1e-3          # PI cannot remove the line
    assert abs(summary["mean_error_K"]) < 1e-4 and summary["lowfreq_rms_K"] < 1e-4
    assert summary["rms_K"] == pytest.approx(summary["ptc_line_amplitude_K"] / 2 ** 0.5, rel=0.1)
    # the whole periodic part against the tracked phase: here the fundamental is all of it
    assert summary["ptc_periodic_amplitude_K"] == pytest.approx(summary["ptc_line_amplitude_K"], rel=0.02)
    assert len(summary["ptc_harmonic_amplitudes_K"]) == 6
    record = read_record(summary["log_path"])
    assert len(record) == 7500 and record.metadata["simulation_transport"] == "in-process"
    scale = record.columns["ff_scale"]
    assert set(scale[np.isfinite(scale)]) == {0.0}                  # --no-feedforward: never faded in


def test_the_feedforward_beats_the_sinusoid_cap_at_5_K(tmp_path, capsys):
    """At 5 K a sinusoid around the 113 mW mean cannot pass 113 mW: about 1.9 times less line. A
    waveform shaped within the heater's bounds does better, and the mean and slow noise stay PI's."""
    assert main(simulate_args(tmp_path, "--duration", "900", "--window", "300", "--json", "--seed", "3")) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["ptc_periodic_amplitude_K"] < 1.73e-3 / 3.0
    # within 5 % of the physical limit computed for this cryostat, heater and loop
    assert summary["feedforward_limited_by"] == "authority" and 0.8 < summary["feedforward_authority"] < 0.9
    assert summary["ptc_periodic_amplitude_K"] < 1.05 * summary["ptc_periodic_limit_K"]
    record = read_record(summary["log_path"])
    limit = record.columns["ff_limit_K"]
    # reported live from what the feedforward learned (plant, line, mean power): this cryostat's limit
    assert record.columns["ff_limit_from"][-1] == "learned" == summary["feedforward_limit_from"]
    assert limit[-1] == pytest.approx(summary["ptc_periodic_limit_K"], rel=0.02)
    assert summary["feedforward_reported_limit_K"] == pytest.approx(limit[-1], rel=1e-4)
    # what would change it: a lower setpoint needs less mean power (less room), a higher one more; at 5 K the
    # waveform rests at 0 W, so a heater with twice R I_max^2 changes (almost) nothing
    changes = {change["change"]: change["ptc_periodic_limit_K"] for change in summary["feedforward_limit_changes"]}
    assert changes["setpoint 4.5 K"] > 1.5 * summary["ptc_periodic_limit_K"] > 3 * changes["setpoint 5.5 K"]
    assert changes["R I_max^2 x 2 (1000 mW)"] == pytest.approx(summary["ptc_periodic_limit_K"], rel=0.01)
    assert abs(summary["mean_error_K"]) < 2e-5 and summary["lowfreq_rms_K"] < 2e-5
    assert summary["overruns"] == 0


def test_sim_model_changes_the_cryostat_but_not_the_controller(tmp_path, capsys):
    """--sim-model: a cryostat whose thermometer lags 0.3 s shows a smaller line; the config is unchanged."""
    model = (CONFIG / "model.yaml").read_text().replace(
        "effects: {}", "effects:\n  sensor_lag: {flange_thermometer_time_constant_s: 0.3}")
    path = tmp_path / "lagging.yaml"
    path.write_text(model)
    assert main(simulate_args(tmp_path, "--duration", "400", "--window", "200", "--json",
                              "--sim-model", str(path))) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["ptc_line_amplitude_K"] < 0.7e-3                   # 1.78 mK / |1 + j 3.25|
    assert read_record(summary["log_path"]).metadata["simulated_model"] == str(path)


def test_simulation_that_fails_exits_1_with_the_reason(tmp_path, capsys, monkeypatch):
    import cryod.service.simulation

    def broken_run(self, duration_s=None):
        raise RuntimeError("instrument opener broke")
    monkeypatch.setattr(cryod.service.simulation.Daemon, "run", broken_run)
    assert main(simulate_args(tmp_path, "--duration", "1")) == 1
    assert "RuntimeError: instrument opener broke" in capsys.readouterr().err


BLAS_THREADS_SEEN = """
import json, threadpoolctl
from cryod.cli import use_one_blas_thread
use_one_blas_thread()
import numpy, scipy.linalg
print(json.dumps([info["num_threads"] for info in threadpoolctl.threadpool_info() if info["user_api"] == "blas"]))
"""


@pytest.mark.system
@pytest.mark.parametrize("chosen, expected", [(None, 1), ("2", min(2, os.cpu_count() or 1))])  # OpenBLAS: at most a thread per core
def test_the_daemon_and_the_model_tools_use_one_blas_thread_unless_the_user_chose(chosen, expected):
    """Two OpenBLAS threads made cryod identify 1.7x slower on an hour (3.2x the CPU) and spin on the loop's cores:
    numpy's and scipy's BLAS libraries (each has its own) both run one thread, unless the environment says."""
    environment = {key: value for key, value in os.environ.items() if not key.endswith("_NUM_THREADS")}
    if chosen is not None:
        environment["OPENBLAS_NUM_THREADS"] = chosen
    output = subprocess.run([sys.executable, "-c", BLAS_THREADS_SEEN], capture_output=True, text=True,
                            env=environment, check=True).stdout
    threads = json.loads(output.strip().splitlines()[-1])
    assert len(threads) == 2 and set(threads) == {expected}, output


@pytest.mark.system
def test_the_control_client_loads_no_blas():
    """``cryod ctl`` answers fast: importing the command line loads neither numpy nor scipy."""
    script = "import sys, cryod.cli; print('numpy' in sys.modules, 'scipy' in sys.modules)"
    output = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True).stdout.split()
    assert output == ["False", "False"]
