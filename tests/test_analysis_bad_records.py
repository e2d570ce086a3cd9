"""Records the analysis cannot use are refused with what they are missing (exit 2), nothing else happens.

Too short a record is the reader's to refuse (tests/test_analyze_command.py);
these are the ones only the analysis can judge: instants that go backwards, most
readings missing, no cooler line in T5, a heater saturated throughout.
"""

import numpy as np
import pytest

from cryod import cli
from cryod.analysis.pipeline import analyze
from cryod.analysis.record_data import RecordData
from cryod.analysis.usability import UnusableRecordError, check_usable
from cryod.records.record import Record, write_record
from simulated_hw.measurement_programs import make_record


@pytest.fixture(scope="module")
def good(reference_model):
    record = make_record(reference_model, "pi_only", duration_s=600.0, seed=1)
    return record.columns, record.metadata


def _data(columns, metadata, source="lab.csv"):
    return RecordData.from_record(Record(dict(metadata), {k: np.asarray(v) for k, v in columns.items()},
                                         source=source))


def _without_line(reference_model):
    record = make_record(reference_model.with_ptc(ptc_stage_amplitude_K=0.0), "pi_only", duration_s=600.0, seed=1)
    return record.columns, record.metadata


def _most_T2_missing(columns):
    mask = np.random.default_rng(0).random(columns["T2_K"].size) < 0.6
    return dict(columns, T2_K=np.where(mask, np.nan, columns["T2_K"]))


def _saturated(reference_model):
    record = make_record(reference_model, "pi_only", duration_s=600.0, seed=1, setpoint_K=9.0)
    return record.columns, record.metadata


def test_a_good_record_passes(good):
    check_usable(_data(*good))


def test_instants_that_go_backwards_are_refused(good):
    columns, metadata = good
    joined = {name: np.concatenate([values[:4000], values[:3500]]) for name, values in columns.items()}
    with pytest.raises(UnusableRecordError, match=r"time does not increase at data row 4001 \(t = 0.000 s\), "
                                                  r"after 319.920 s.*split the record") as caught:
        analyze(_data(joined, metadata), None)
    assert "lab.csv" in str(caught.value)


def test_most_readings_missing_is_refused(good):
    columns, metadata = good
    with pytest.raises(UnusableRecordError, match=r"'T2_K' is missing \(empty or NaN\) in 60 % of the rows, the "
                                                  r"first at data row 2 \(t = 0.080 s\)"):
        analyze(_data(_most_T2_missing(columns), metadata), None)


def test_no_cooler_line_in_T5_is_refused(reference_model):
    with pytest.raises(UnusableRecordError, match=r"T5_K shows no line of the cooler.*was the cooler running"):
        analyze(_data(*_without_line(reference_model)), reference_model)


def test_a_heater_saturated_throughout_is_refused(reference_model):
    columns, metadata = _saturated(reference_model)
    assert np.ptp(columns["heater_W"]) == 0.0
    with pytest.raises(UnusableRecordError, match=r"heater is saturated throughout: heater_W is 0.25 W \(at its "
                                                  r"limit\) in every row while the setpoint asks for regulation"):
        analyze(_data(columns, metadata), reference_model)


def test_an_open_loop_hold_at_one_power_is_still_analysed(good):
    """A constant heater with the loop open is a hold, not a saturation: the line alone can be analysed."""
    columns, metadata = good
    hold = dict(columns, heater_W=np.full(columns["heater_W"].size, 0.02), setpoint_K=np.full(columns["T2_K"].size,
                                                                                              np.nan))
    check_usable(_data(hold, metadata))


@pytest.mark.parametrize("case", ["most T2 missing", "no line", "saturated"])
def test_the_command_refuses_them_with_exit_2_and_writes_nothing(case, good, reference_model, tmp_path, capsys):
    columns, metadata = {"most T2 missing": lambda: (_most_T2_missing(good[0]), good[1]),
                         "no line": lambda: _without_line(reference_model),
                         "saturated": lambda: _saturated(reference_model)}[case]()
    path = write_record(tmp_path / "bad.csv", columns, metadata)
    status = cli.main(["analyze", str(path), "--out", str(tmp_path / "out"), "--json"])
    captured = capsys.readouterr()
    assert status == 2 and captured.out == ""
    assert captured.err.startswith(f"cryod analyze: {path}: ")
    assert not (tmp_path / "out").exists()


def test_a_wandering_cooler_on_jittered_instants_is_a_line_not_noise():
    """A 10 Hz record with 20 ms of trigger jitter and a cooler wandering +-1 %: one frequency over the whole
    record would smear the line into the residual (6.7 times the noise, 'T5 shows no line'); its tracked
    phase keeps it a line."""
    generator = np.random.default_rng(3)
    time_s = np.cumsum(0.1 + generator.uniform(0.0, 0.02, 24000))
    phase = 10.83 * time_s + 0.01 * 10.83 * 900.0 / (2 * np.pi) * (1 - np.cos(2 * np.pi * time_s / 900.0))
    stage = 3.34 + 0.12 * np.sin(phase) + generator.normal(0.0, 3e-4, time_s.size)
    data = RecordData(time_s, 4.23 + 0 * time_s, stage, 0.1 + 0.01 * (time_s > 600), np.full(time_s.size, np.nan),
                      source="wandering.csv")
    check_usable(data)                                   # no refusal
    flat = RecordData(time_s, 4.23 + 0 * time_s, 3.34 + generator.normal(0.0, 3e-4, time_s.size),
                      0.1 + 0.01 * (time_s > 600), np.full(time_s.size, np.nan), source="flat.csv")
    with pytest.raises(UnusableRecordError, match="shows no line"):
        check_usable(flat)
