"""``cryod analyze`` end to end: files, JSON contract, extended model, bad input, the paper's measurements."""

import contextlib
import hashlib
import io
import json
import subprocess
import sys

import numpy as np
import pytest

from cryod import cli
from cryod.analysis.summary import CAUSES
from cryod.model import DeadTime, load_model
from cryod.analysis.paper_table1 import regenerated_record
from cryod.records.record import write_record
from simulated_hw.measurement_programs import make_record

from tests.conftest import CONFIG, REPOSITORY

METADATA = {"heater_resistance_ohm": "25.0", "heater_current_limit_A": "0.1"}


def _write(path, columns, metadata=METADATA):
    write_record(path, columns, metadata)
    return path


def _analyze(capsys, *arguments):
    status = cli.main(["analyze", *map(str, arguments)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.fixture(scope="module")
def dead_time_record(tmp_path_factory, reference_model):
    record = make_record(reference_model.with_effects(dead_time=DeadTime(1.5)).with_ptc(phase_rad=0.5),
                         "identification", duration_s=1200.0, seed=8)
    return _write(tmp_path_factory.mktemp("records") / "dead-time.csv", record.columns, record.metadata)


def test_analyze_writes_report_figures_model_and_json(dead_time_record, tmp_path, capsys):
    before = hashlib.sha256(dead_time_record.read_bytes()).hexdigest()
    status, out, err = _analyze(capsys, dead_time_record, "--out", tmp_path / "analysis", "--json")
    assert status == 0, err
    result = json.loads(out)
    assert set(result) == {"cause", "causes", "recalibrated", "discrepancies", "extended_model", "gain",
                           "candidates", "remaining", "base_model_off", "generic_extension", "residual_signature",
                           "at_bound", "attribution"}
    assert result["at_bound"] == []                      # a 4 s dead time is well within its range
    assert result["base_model_off"] is None and result["remaining"]["discrepancy"] is False
    assert result["causes"][0]["equivalent_to"] == []
    assert {"spectral_peaks", "drift", "cross_correlations", "segments", "resid"} <= set(result["residual_signature"])
    assert [named["cause"] for named in result["causes"]] == ["dead_time"]
    assert {"parameters", "explained_fraction", "gain"} <= set(result["causes"][0])
    assert {row["parameter"] for row in result["recalibrated"]["parameters"]} >= {
        "heater_to_flange static gain", "flange_to_thermometer time constant", "line gain on T2",
        "line phase on T2", "operating point T2_0", "T2 white noise rms"}
    assert all({"shipped", "fitted", "uncertainty", "significance"} <= set(row)
               for row in result["recalibrated"]["parameters"])
    assert result["cause"] == "dead_time" and result["cause"] in CAUSES
    assert all(set(d) == {"quantity", "model", "measured", "significance"} for d in result["discrepancies"])
    assert max(d["significance"] for d in result["discrepancies"]) > 100.0
    assert set(result["gain"]) == {"metric", "base", "extended", "ratio"} and result["gain"]["ratio"] > 5.0
    assert sorted(c["cause"] for c in result["candidates"]) == sorted(set(CAUSES) - {"none", "unexplained",
                                                                                   "base_model_off"})
    assert CAUSES == ("none", "sensor_lag", "link_dynamics", "dead_time", "heat_capacity_temperature",
                      "heater_nonlinearity", "ptc_harmonics", "ptc_frequency_drift", "ptc_amplitude_modulation",
                      "ptc_stage_drift", "unexplained", "base_model_off")
    assert all({"score", "parameters"} <= set(c) for c in result["candidates"])
    extended = load_model(result["extended_model"])
    assert extended.effects.dead_time.heater_to_flange_s == pytest.approx(1.5, rel=0.02)
    directory = tmp_path / "analysis"
    for name in ("report.md", "overview.png", "residual_spectrum.png", "ptc_line.png", "candidates.png",
                 "steps.png", "correlation.png", "analysis.json"):
        assert (directory / name).stat().st_size > 1000, name
    report = (directory / "report.md").read_text()
    assert "Cause: `dead_time`" in report and "![" in report
    assert json.loads((directory / "analysis.json").read_text()) == result
    assert hashlib.sha256(dead_time_record.read_bytes()).hexdigest() == before     # the record is only read

    # the extended model explains the record, and the simulator runs it
    status, out, err = _analyze(capsys, dead_time_record, "--model", result["extended_model"], "--out",
                                tmp_path / "again", "--json", "--no-figures")
    assert status == 0 and json.loads(out)["cause"] == "none", err
    assert cli.main(["--simulate", "--sim-model", result["extended_model"], "--duration", "8", "--speed", "max",
                     "--data-dir", str(tmp_path / "data"), "--socket", str(tmp_path / "c.sock"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["ticks"] == 100 and summary["log_path"].startswith(str(tmp_path))


def test_missing_column_is_refused_with_its_name(tmp_path, capsys):
    path = tmp_path / "broken.csv"
    path.write_text("# cryod-log v1\ntime_s,T2_K,heater_W,setpoint_K\n0.0,4.23,0.0,\n")
    status, out, err = _analyze(capsys, path, "--out", tmp_path / "out")
    assert status == 2 and "T5_K" in err and "broken.csv" in err
    assert not (tmp_path / "out").exists()


def test_malformed_model_is_refused_with_file_and_key(dead_time_record, tmp_path, capsys):
    model = tmp_path / "bad-model.yaml"
    model.write_text((CONFIG / "model.yaml").read_text().replace("denominator: [26.48, 1.0]",
                                                                 "denominator: [-26.48, 1.0]"))
    status, out, err = _analyze(capsys, dead_time_record, "--model", model, "--out", tmp_path / "out")
    assert status == 2 and "bad-model.yaml" in err and "flange_to_thermometer" in err


def test_short_or_missing_record_is_refused(tmp_path, capsys):
    t = np.arange(0.0, 30.0, 0.08)
    path = _write(tmp_path / "short.csv", {"time_s": t, "T2_K": 4.23 + 0 * t, "T5_K": 3.34 + 0 * t,
                                            "heater_W": 0 * t, "setpoint_K": np.nan * t})
    status, _, err = _analyze(capsys, path)
    assert status == 2 and "too short" in err
    status, _, err = _analyze(capsys, tmp_path / "nothing.csv")
    assert status == 2 and "file not found" in err


def test_analyze_help_from_the_command_line():
    done = subprocess.run([sys.executable, "-m", "cryod.cli", "analyze", "--help"], capture_output=True, text=True,
                          cwd=REPOSITORY, check=False)
    assert done.returncode == 0 and "--model" in done.stdout and "--json" in done.stdout


# -- the paper's own measurements ----------------------------------------------------------
@pytest.fixture(scope="module")
def table1_record(tmp_path_factory):
    return _write(tmp_path_factory.mktemp("paper") / "table1.csv", regenerated_record(duration_s=1200.0, seed=3),
                  {"source": "Pan et al. Part 1, Table 1, regenerated"})


def test_printed_model_on_the_papers_measurements(table1_record, tmp_path, capsys):
    """The printed equations put 0.825 rad too much lag on T2's line: link_dynamics, refitted to the measured link."""
    status, out, err = _analyze(capsys, table1_record, "--model", CONFIG / "model-paper-printed.yaml", "--out",
                                tmp_path, "--json", "--no-figures")
    assert status == 0, err
    result = json.loads(out)
    assert result["cause"] == "link_dynamics"
    assert result["gain"]["ratio"] > 10.0
    link = load_model(result["extended_model"]).ptc_to_flange
    shipped = load_model(CONFIG / "model.yaml").ptc_to_flange
    assert link.frequency_response(10.83) == pytest.approx(shipped.frequency_response(10.83), rel=0.01)
    assert link.denominator[0] == pytest.approx(0.1996, rel=0.02)


@pytest.fixture(scope="module")
def shipped_analysis(table1_record, tmp_path_factory):
    """``cryod analyze RECORD --json --no-figures`` on a copy of the paper's record with the shipped model, run from
    another folder: (the record, that folder, its JSON output). Read by the two tests below."""
    folder = tmp_path_factory.mktemp("shipped")
    record = folder / "records" / "run.csv"
    record.parent.mkdir()
    record.write_bytes(table1_record.read_bytes())
    with pytest.MonkeyPatch.context() as patch, contextlib.redirect_stdout(io.StringIO()) as out:
        patch.chdir(folder)                           # not where the analysis goes
        status = cli.main(["analyze", str(record), "--json", "--no-figures"])
    assert status == 0
    return record, folder, json.loads(out.getvalue())


def test_shipped_model_explains_the_flange_in_the_papers_measurements(shipped_analysis):
    _, _, result = shipped_analysis
    assert result["cause"] in ("none", "unexplained")
    flange = [d for d in result["discrepancies"] if d["quantity"].startswith("T2 residual rms")]
    assert flange and all(d["measured"] < 1.05 * d["model"] for d in flange)
    assert all(c["score"] < 25.0 or c["significance"] < 5.0 for c in result["candidates"])


def test_the_analysis_goes_beside_the_record_and_an_earlier_one_is_kept_without_force(shipped_analysis, capsys,
                                                                                        monkeypatch):
    record, folder, result = shipped_analysis
    monkeypatch.chdir(folder)
    beside = folder / "records" / "run-analysis"
    assert result["extended_model"] == str(beside / "extended-model.yaml")
    written = (beside / "analysis.json").read_bytes()
    status, _, err = _analyze(capsys, record, "--json", "--no-figures")
    assert status == 2 and "holds an earlier analysis (analysis.json); give --force" in err
    assert (beside / "analysis.json").read_bytes() == written
    status, _, err = _analyze(capsys, record, "--json", "--no-figures", "--force")
    assert status == 0, err
    assert not (folder / "run-analysis").exists()
