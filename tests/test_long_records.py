"""Long records: read in memory proportional to their numbers, analysed on a bounded stretch,
bad lines named wherever they are."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest

from cryod.records.record import RecordFormatError, read_record, read_record_text

#: What the daemon writes, less the control terms' columns.
NAMES = ("time_s,T2_K,T5_K,heater_W,setpoint_K,T2_ohm,T5_ohm,T2_sample_s,T5_sample_s,heater_set_s,"
         "trigger_skew_ms,lateness_ms,cycle_ms,pi_proportional_W,pi_integral_W,state")
HEADER = f"# cryod-log v1\n# loop_period_s: 0.08\n# heater_resistance_ohm: 50.0\n{NAMES}\n"


def daemon_like_lines(rows: int, period_s: float = 0.08, step_at_s: float | None = None) -> list[str]:
    """Data lines formatted as the daemon formats them: open loop for 10 s (empty setpoint), then closed;
    an event line after the 10 s. With ``step_at_s``, the heater steps from 50 to 100 mW there for 1000 s."""
    lines = []
    for row in range(rows):
        t = (row + 1) * period_s
        line_phase = 10.83 * t
        flange = 4.23 + 0.0017 * math.sin(line_phase + 1.89)
        stage = 3.34 + 0.12 * math.sin(line_phase + 3.02)
        heater = 0.05
        if step_at_s is not None and step_at_s <= t < step_at_s + 1000.0:
            heater = 0.1
        setpoint = f"{5.0:.7f}" if t > 10.0 else ""
        state = "closed" if t > 10.0 else "holding"
        lines.append(f"{t:.4f},{flange:.7f},{stage:.6f},{heater:.6e},{setpoint},{2754.18 - 10 * (flange - 4.23)!r},"
                     f"{711.88 - (stage - 3.34)!r},{t + 0.01:.5f},{t + 0.01:.5f},{t + 0.0425:.5f},0.0,0.0,"
                     f"{42.5 + (row % 7) / 10!r},{0.01 * math.sin(line_phase)!r},0.05,{state}\n")
        if row == int(10.0 / period_s):
            lines.append("# event: resumed: 5 valid readings after holding; state closed\n")
    return lines


def write_daemon_like(path, rows: int, **options):
    path.write_text(HEADER + "".join(daemon_like_lines(rows, **options)), encoding="utf-8")
    return path


def traced_peak_bytes(function, *args, **kwargs):
    """(result, peak bytes allocated while it ran, as tracemalloc counts them)."""
    tracemalloc.start()
    try:
        result = function(*args, **kwargs)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return result, peak


# -- reading --------------------------------------------------------------------
def test_reading_a_long_record_holds_its_numbers_not_its_text(tmp_path):
    peaks, held = [], []
    for rows in (6000, 30_000):
        path = write_daemon_like(tmp_path / f"{rows}.csv", rows)
        record, peak = traced_peak_bytes(read_record, path)
        assert len(record) == rows and record.columns["state"][-1] == "closed"
        assert record.events == [(126, "event: resumed: 5 valid readings after holding; state closed")]
        peaks.append(peak)
        held.append(sum(column.nbytes for column in record.columns.values()))
    # each added row costs its numbers (and the text column's string while that column is made), not its text:
    # reading the whole text into rows of fields first cost 12 times the numbers
    growth = (peaks[1] - peaks[0]) / (held[1] - held[0])
    assert growth < 2.0, growth
    assert peaks[1] < 2.0 * held[1] + 5e6, (peaks[1] / 1e6, held[1] / 1e6)


def test_the_analysis_reads_only_its_columns_in_memory_near_their_size(tmp_path):
    from cryod.analysis.record_data import ANALYSED_COLUMNS, read_record_data

    peaks, held = [], []
    for rows in (6000, 30_000):
        path = write_daemon_like(tmp_path / f"{rows}.csv", rows)
        data, peak = traced_peak_bytes(read_record_data, path)
        assert data.time_s.size == rows and data.time_s[0] == pytest.approx(0.09)      # T2_sample_s
        peaks.append(peak)
        held.append(sum(getattr(data, name).nbytes for name in ("time_s", "flange_K", "ptc_stage_K", "heater_w",
                                                                  "setpoint_K", "heater_change_s")))
    growth = (peaks[1] - peaks[0]) / (held[1] - held[0])
    assert growth < 2.0, growth
    partial = read_record(path, columns=ANALYSED_COLUMNS)
    assert set(partial.columns) == {"time_s", "T2_K", "T5_K", "heater_W", "setpoint_K", *ANALYSED_COLUMNS}


def test_columns_asked_for_are_read_exactly_and_the_others_skipped(tmp_path):
    path = write_daemon_like(tmp_path / "long.csv", 5000)
    whole = read_record(path)
    partial = read_record(path, columns=["lateness_ms", "state", "not_in_this_record"])
    assert list(partial.columns) == ["time_s", "T2_K", "T5_K", "heater_W", "setpoint_K", "lateness_ms", "state"]
    for name, values in partial.columns.items():
        np.testing.assert_array_equal(values, whole.columns[name])
    assert partial.events == whole.events and partial.metadata == whole.metadata
    assert np.isnan(partial.setpoint_K[0]) and partial.setpoint_K[-1] == 5.0


def test_a_bad_cell_deep_in_a_long_record_names_its_line_and_column(tmp_path):
    lines = daemon_like_lines(5000)
    fields = lines[4000].split(",")
    fields[2] = "3.3x"
    lines[4000] = ",".join(fields)
    path = tmp_path / "bad.csv"
    path.write_text(HEADER + "".join(lines), encoding="utf-8")
    for columns in (None, ["T2_sample_s"]):
        with pytest.raises(RecordFormatError, match="column 'T5_K': not a number: '3.3x'") as caught:
            read_record(path, columns=columns)
        assert caught.value.line == HEADER.count("\n") + 4001 and caught.value.source == str(path)


def test_a_column_that_turns_to_text_after_the_first_lines_is_read_as_text_exactly():
    lines = daemon_like_lines(3000)
    fields = lines[2500].split(",")
    fields[11] = "late"                          # lateness_ms, numbers until here
    lines[2500] = ",".join(fields)
    record = read_record_text(HEADER + "".join(lines), columns=["lateness_ms"])
    assert record.columns["lateness_ms"].dtype.kind == "U"
    assert record.columns["lateness_ms"][0] == "0.0" and record.columns["lateness_ms"][2499] == "late"
    assert record.time_s.size == 3000


def test_a_killed_writers_last_line_cut_inside_a_number_is_dropped_and_its_column_stays_numeric():
    text = ("# cryod-log v1\ntime_s,T2_K,T5_K,heater_W,setpoint_K,lateness_ms\n"
            + "".join(f"{0.08 * (row + 1):.4f},4.23,3.34,0.05,5.0,0.{row % 10}\n" for row in range(3000))
            + "240.0800,4.23,3.34,0.05,5.0,1.2e")                          # "1.2e-03" when the writer was killed
    record = read_record_text(text)
    assert record.time_s.size == 3000 and record.warnings == ["line 3003: last line cut short, dropped"]
    assert record.columns["lateness_ms"].dtype == float and record.columns["lateness_ms"][-1] == 0.9


def test_a_record_that_is_not_utf8_names_its_first_bad_line(tmp_path):
    path = tmp_path / "damaged.csv"
    lines = daemon_like_lines(3000)
    path.write_bytes((HEADER + "".join(lines[:2000])).encode() + b"0.1\xff\xfe,4.2\n" + "".join(lines[2000:]).encode())
    with pytest.raises(RecordFormatError, match="not UTF-8 text: byte 0xff at character 4") as caught:
        read_record(path)
    assert caught.value.line == HEADER.count("\n") + 2001


# -- the analysed stretch ---------------------------------------------------------------
def test_a_long_record_is_analysed_on_the_stretch_where_the_heater_moves_most():
    from cryod.analysis.record_data import RecordData, analysed_stretch
    from cryod.analysis.record_window import busiest_stretch
    from cryod.records.record import Record

    time_s = np.arange(0.08, 6 * 3600.0, 0.08)
    heater = np.where((time_s > 14000.0) & (time_s < 15000.0), 0.1, 0.05)
    heater = heater + 0.04 * np.sin(10.83 * time_s)                          # a feedforward's line: averaged out
    start, stop = busiest_stretch(time_s, heater, 7200.0)
    assert time_s[start] <= 14000.0 and time_s[stop - 1] >= 15000.0
    assert time_s[stop - 1] - time_s[start] == pytest.approx(7200.0, abs=0.1)
    assert busiest_stretch(time_s, np.full(time_s.size, 0.05), 7200.0)[0] == 0     # equal stretches: the earliest
    assert busiest_stretch(time_s[:1000], heater[:1000], 7200.0) == (0, 1000)     # shorter: all of it

    flange = 4.23 + 0.0017 * np.sin(10.83 * time_s)
    record = Record({}, {"time_s": time_s, "T2_K": flange, "T5_K": flange - 0.9, "heater_W": heater,
                         "setpoint_K": np.full(time_s.size, np.nan)}, source="six hours")
    data = RecordData.from_record(record)
    part = analysed_stretch(data, 7200.0)
    assert part.duration_s == pytest.approx(7200.0, abs=0.1) and part.time_s[0] == time_s[start]
    assert part.notes[-1].startswith("analysed 2.00 h of the record's 6.00 h: t = ")
    assert analysed_stretch(data, 0.0) is data and analysed_stretch(data, 30000.0) is data


def test_analyze_says_which_stretch_it_analysed(tmp_path, capsys, monkeypatch):
    from cryod import cli
    from cryod.cli import analyze as command

    path = write_daemon_like(tmp_path / "long.csv", 20_000, step_at_s=1000.0)       # 1600 s
    seen = {}

    def analyse_and_write(data, *args, **kwargs):
        seen["data"] = data
        return {"cause": "none", "gain": {"ratio": 1.0, "metric": "-"}, "extended_model": "-"}

    monkeypatch.setattr(command, "analyse_and_write", analyse_and_write)
    assert cli.main(["analyze", str(path), "--max-duration", "600", "--out", str(tmp_path / "out")]) == 0
    assert seen["data"].duration_s == pytest.approx(600.0, abs=0.1)
    assert 400.0 <= seen["data"].time_s[0] <= 1000.0          # holds the step up at 1000 s
    assert "analysed 0.17 h of the record's 0.44 h" in capsys.readouterr().err
    assert cli.main(["analyze", str(path), "--max-duration", "0", "--out", str(tmp_path / "out")]) == 0
    assert seen["data"].duration_s == pytest.approx(1600.0, abs=0.1)


def test_identify_fits_the_stretch_asked_for_and_says_so(tmp_path, capsys, reference_model):
    from cryod import cli
    from cryod.records.record import write_record
    from simulated_hw.measurement_programs import make_record

    made = make_record(reference_model, "pi_only", duration_s=2400.0, seed=4)
    path = write_record(tmp_path / "pi.csv", made.columns, made.metadata)
    status = cli.main(["identify", str(path), "--max-duration", "1200", "--bootstrap", "0", "--max-terms", "2",
                       "--out", str(tmp_path / "model.yaml")])
    stderr = capsys.readouterr().err
    assert status == 0, stderr
    assert "pi.csv: fitted 0.33 h of the record's 0.67 h: t = 0.0 s to 1200.0 s" in stderr


# -- a long record through the commands, as a lab runs them (slow) ------------------------------------------
@pytest.mark.slow
def test_a_six_hour_record_with_a_hidden_effect_is_analysed_and_identified_in_bounded_memory(tmp_path,
                                                                                          reference_model):
    import json

    from cryod.model import DeadTime
    from cryod.records.record import write_record
    from simulated_hw.measurement_programs import make_record
    from tests.measured_child import run_cryod

    made = make_record(reference_model.with_effects(dead_time=DeadTime(1.5)), "pi_only", duration_s=6 * 3600.0,
                       seed=5)
    path = write_record(tmp_path / "six-hours.csv", made.columns, made.metadata)

    def measured(*arguments):
        child = run_cryod(list(arguments), tmp_path)        # the child's own peak and CPU (tests/measured_child.py)
        return child.status, child.stdout, child.stderr, child.cpu_s, child.peak_MB

    status, stdout, stderr, cpu_s, peak_MB = measured("analyze", str(path), "--json", "--out", "analysis")
    assert status == 0, stderr
    assert json.loads(stdout)["cause"] == "dead_time"
    assert "analysed 2.00 h of the record's 6.00 h: t = 0.0 s to 7200.0 s" in stderr
    # two hours of it, with figures: about 265 MB and 20 s of CPU (the whole record would take 620 MB and 53 s)
    assert peak_MB < 400.0 and cpu_s < 40.0, (peak_MB, cpu_s)

    status, stdout, stderr, cpu_s, peak_MB = measured("identify", str(path), "--json", "--out", "identified.yaml")
    assert status == 0, stderr
    assert json.loads(stdout)["heater_to_ptc_stage_time_constant_s"] == pytest.approx(135.0, rel=0.01)
    # all six hours, with 30 bootstrap refits: about 285 MB and 115 s of CPU (reading the whole text and keeping
    # every evaluation's design and a scaled copy would take 445 MB)
    assert peak_MB < 350.0 and cpu_s < 240.0, (peak_MB, cpu_s)
