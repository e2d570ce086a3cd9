import numpy as np
import pytest

from cryod.records.record import RecordFormatError, format_header, format_row, read_record, read_record_text, write_record

HEADER = "# cryod-log v1\n# heater_resistance_ohm: 50.0 ohm\ntime_s,T2_K,T5_K,heater_W,setpoint_K,flags\n"


def test_reads_contract_example_and_ignores_unknown_columns():
    record = read_record_text(HEADER + "0.0800,4.2306589,3.256174,0.000000e+00,,ok\n0.1600,4.2306,3.25,1e-3,5.0,ok\n")
    assert record.time_s.tolist() == [0.08, 0.16]
    assert np.isnan(record.setpoint_K[0]) and record.setpoint_K[1] == 5.0
    assert record.columns["flags"].tolist() == ["ok", "ok"]
    assert record.metadata_number("heater_resistance_ohm") == 50.0


def test_missing_required_column_is_named():
    text = "# cryod-log v1\ntime_s,T2_K,heater_W,setpoint_K\n0.08,4.23,0,\n"
    with pytest.raises(RecordFormatError, match="required column 'T5_K' is missing") as caught:
        read_record_text(text, "day.csv")
    assert caught.value.line == 2


def test_bad_value_names_line_and_column():
    with pytest.raises(RecordFormatError, match="column 'T2_K': not a number: 'warm'") as caught:
        read_record_text(HEADER + "0.08,4.23,3.3,0,,ok\n0.16,warm,3.3,0,,ok\n", "day.csv")
    assert caught.value.line == 5


def test_not_a_record_and_time_going_backwards():
    with pytest.raises(RecordFormatError, match="not a cryod-log v1"):
        read_record_text("time_s,T2_K\n")
    with pytest.raises(RecordFormatError, match="does not increase") as caught:
        read_record_text(HEADER + "0.16,4.23,3.3,0,,a\n0.08,4.23,3.3,0,,b\n")
    assert caught.value.line == 5


def test_cut_short_last_line_is_dropped_and_the_rest_kept():
    record = read_record_text(HEADER + "0.08,4.23,3.3,0,,ok\n0.16,4.2")
    assert len(record) == 1 and "cut short" in record.warnings[0]
    record = read_record_text(HEADER + "0.08,4.23,3.3,0,,ok\n0.16,4.23,3.3,1.2e")   # right field count, cut number
    assert len(record) == 1 and record.warnings


def test_events_keep_their_place():
    record = read_record_text(HEADER + "0.08,4.23,3.3,0,,ok\n# fault: over_temperature\n0.16,4.23,3.3,0,,heater_off\n")
    assert record.events == [(1, "fault: over_temperature")]


def test_write_then_read_round_trip_and_never_overwrite(tmp_path):
    path = tmp_path / "made.csv"
    columns = {"time_s": [0.08, 0.16], "T2_K": [4.2306589, 4.23], "T5_K": [3.256174, 3.3],
               "heater_W": [0.0, 0.11], "setpoint_K": [None, 5.0], "lateness_ms": [0.1, 0.2]}
    write_record(path, columns, {"note": "two\nlines"})
    record = read_record(path)
    assert record.flange_K.tolist() == [4.2306589, 4.23]
    assert record.columns["lateness_ms"].tolist() == [0.1, 0.2]
    assert path.read_text().splitlines()[1:3] == ["# note: two", "# note: lines"]
    assert record.metadata["note"] == "two\nlines"
    with pytest.raises(FileExistsError):
        write_record(path, columns)


def test_row_format_matches_contract():
    names = ["time_s", "T2_K", "T5_K", "heater_W", "setpoint_K"]
    assert format_row(names, {"time_s": 0.08, "T2_K": 4.2306589, "T5_K": 3.256174, "heater_W": 0.0,
                              "setpoint_K": None}) == "0.0800,4.2306589,3.256174,0.000000e+00,\n"
    assert format_header({}, names) == "# cryod-log v1\ntime_s,T2_K,T5_K,heater_W,setpoint_K\n"


def test_multi_line_metadata_keeps_its_indentation(tmp_path):
    config_text = "control:\n  setpoint_K: 5.0\n  ramp_K_per_min: 0.0\n"
    path = write_record(tmp_path / "r.csv", {"time_s": [0.08], "T2_K": [4.23], "T5_K": [3.34], "heater_W": [0.0],
                                            "setpoint_K": [None]}, {"config": config_text})
    assert read_record(path).metadata["config"] == config_text.rstrip("\n")
