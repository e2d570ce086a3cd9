"""Records that last: meaningful precision, finished days compressed, and the readers users have."""

import gzip
import threading

import numpy as np
import pandas
import pytest

import cryod
from cryod.records import compression
from cryod.records.columns import REQUIRED, STATE, Row, RowSchema
from cryod.records.datalog import DataLog
from cryod.records.record import RecordFormatError, read_record
from cryod.service.daemon import Daemon
from cryod.service.notify import SystemdNotifier
from drivers.clock import VirtualClock
from cryod.service.simulation import SimulatedInstrumentsOpener
from tests.example_config import simulated_config
from tests.record_rows import rows

SCHEMA = RowSchema(REQUIRED + (STATE,))
MIDNIGHT = 1_795_046_400.0         # 2026-11-19 00:00:00 UTC


def test_a_finished_day_is_compressed_when_the_next_day_starts_and_reads_back_the_same(tmp_path):
    datalog = DataLog(tmp_path, SCHEMA, {"site": "test"}, lambda t: MIDNIGHT - 4.0 + t, 0.08, 0.5,
                      compress_finished=True)
    datalog.start()
    for row in rows(0.08, 100):        # 8 s across midnight
        datalog.put(row)
    datalog.stop()
    assert sorted(path.name for path in tmp_path.iterdir()) == ["cryod-2026-11-18.csv.gz", "cryod-2026-11-19.csv"]
    text = gzip.decompress((tmp_path / "cryod-2026-11-18.csv.gz").read_bytes()).decode()
    assert text.startswith("# cryod-log v1\n")
    finished = read_record(tmp_path / "cryod-2026-11-18.csv.gz")
    assert len(finished) + len(read_record(tmp_path / "cryod-2026-11-19.csv")) == 100
    frame = pandas.read_csv(tmp_path / "cryod-2026-11-18.csv.gz", comment="#")     # pandas takes .gz as it is
    # what the run's summary names is where each record is now, the finished day's compressed
    assert datalog.written_paths() == [tmp_path / "cryod-2026-11-18.csv.gz", tmp_path / "cryod-2026-11-19.csv"]
    assert np.allclose(frame["T2_K"].to_numpy(), finished.flange_K)
    # a restart on the finished day does not reuse its name
    again = DataLog(tmp_path, SCHEMA, {}, lambda t: MIDNIGHT - 100.0 + t, 0.08, 0.5)
    again.start()
    for row in rows(0.08, 5):
        again.put(row)
    again.stop()
    assert again.paths[0].name == "cryod-2026-11-18.2.csv"


def test_a_daemon_on_a_virtual_clock_dates_its_record_from_the_clocks_wall_start(tmp_path, reference_model):
    """A run dated 30 s before midnight splits its record there, the finished day compressed."""
    clock = VirtualClock()
    clock.wall_start_s = MIDNIGHT - 30.0
    config = simulated_config(tmp_path)
    result = Daemon(config, SimulatedInstrumentsOpener(reference_model, seed=1), clock,
                    notifier=SystemdNotifier({}), install_signal_handlers=False).run(60.0)
    assert result.exit_code == 0
    assert [path.name for path in result.log_paths] == ["cryod-2026-11-18.csv.gz", "cryod-2026-11-19.csv"]
    first, second = (read_record(path) for path in result.log_paths)
    assert len(first) == pytest.approx(30.0 / 0.08, abs=2) and len(second) == pytest.approx(30.0 / 0.08, abs=2)


def test_a_day_that_ends_while_the_day_before_is_still_compressing_is_compressed_too(tmp_path, monkeypatch):
    """Two midnights in one run, the first day's compression held until after the second: both
    finished days end compressed, in turn, none left for the next start."""
    release = threading.Event()
    original = compression.compress_finished
    days_compressed = []

    def slow_at_first(directory, today):
        if not days_compressed:
            release.wait(10.0)
        days_compressed.append(today)
        original(directory, today)

    monkeypatch.setattr(compression, "compress_finished", slow_at_first)
    datalog = DataLog(tmp_path, SCHEMA, {}, lambda t: MIDNIGHT - 43200.0 + t * 86400.0 / 4.0, 0.08, 0.5,
                      compress_finished=True)
    datalog.start()
    for row in rows(0.08, 100):        # 8 s of rows, each second of them a quarter day: two midnights
        datalog.put(row)
    datalog.drain()
    release.set()
    datalog.stop()
    names = sorted(path.name for path in tmp_path.iterdir())
    assert names == ["cryod-2026-11-18.csv.gz", "cryod-2026-11-19.csv.gz", "cryod-2026-11-20.csv"]
    assert days_compressed == ["2026-11-18", "2026-11-19", "2026-11-20"]


def test_compression_never_loses_the_text_and_redoes_an_interrupted_one(tmp_path, monkeypatch):
    record = tmp_path / "cryod-2026-11-17.csv"
    record.write_text("# cryod-log v1\ntime_s,T2_K,T5_K,heater_W,setpoint_K\n0.08,4.23,3.3,0,\n")
    (tmp_path / "cryod-2026-11-17.csv.gz.partial").write_bytes(b"cut short by a crash")
    today = tmp_path / "cryod-2026-11-19.csv"
    today.write_text(record.read_text())

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(compression.shutil, "copyfileobj", full_disk)
    assert compression.compress_finished(tmp_path, "2026-11-19") == []
    assert record.exists() and not (tmp_path / "cryod-2026-11-17.csv.gz").exists()
    assert not list(tmp_path.glob("*.partial"))
    monkeypatch.undo()
    assert compression.compress_finished(tmp_path, "2026-11-19") == [tmp_path / "cryod-2026-11-17.csv.gz"]
    assert not record.exists() and today.exists()                  # today's file is not finished
    assert read_record(tmp_path / "cryod-2026-11-17.csv.gz").flange_K.tolist() == [4.23]


def test_a_damaged_compressed_record_says_so(tmp_path):
    path = tmp_path / "cryod-2026-11-17.csv.gz"
    path.write_bytes(gzip.compress(b"# cryod-log v1\ntime_s,T2_K,T5_K,heater_W,setpoint_K\n0.08,4.23,3.3,0,\n")[:30])
    with pytest.raises(RecordFormatError, match="cryod-2026-11-17.csv.gz.*cannot read"):
        read_record(path)


def test_daemon_rows_carry_meaningful_digits_only(tmp_path):
    import io

    run = cryod.simulate(30.0, data_dir=tmp_path / "data", socket=tmp_path / "c.sock", log_stream=io.StringIO())
    lines = [line for line in run.log_paths[0].read_text().splitlines() if not line.startswith("#")]
    names = lines[0].split(",")
    last = dict(zip(names, lines[-1].split(",")))
    for name in ("cycle_ms", "lateness_ms"):
        assert len(last[name].split(".")[1]) == 2, last[name]           # 10 µs
    for name in ("pi_proportional_W", "pi_integral_W", "ff_W"):
        assert "e" in last[name] and len(last[name].split("e")[0]) <= 9, last[name]     # 7 digits
    # the header (the configuration's snapshot, 10 kB) is written once a file: over an hour it is nothing
    text = run.log_paths[0].read_text()
    header = text[:text.index(lines[0])]
    bytes_per_row = (len(text.encode()) - len(header.encode())) / (len(lines) - 1)
    assert bytes_per_row < 240                                            # 10 MB an hour at most


def test_the_supported_readers_read_a_daemon_record(tmp_path):
    import io

    run = cryod.simulate(30.0, data_dir=tmp_path / "data", socket=tmp_path / "c.sock", log_stream=io.StringIO())
    path = run.log_paths[0]
    record = cryod.read_record(path)
    frame = pandas.read_csv(path, comment="#")                             # events are comment lines too
    assert len(frame) == len(record) == 375
    assert np.allclose(frame["T2_K"], record.flange_K) and frame["state"].iloc[-1] == record.columns["state"][-1]
    # numpy: the header's comment lines must be skipped, or genfromtxt takes "# cryod-log v1" for the names
    table = np.genfromtxt(path, delimiter=",", names=True, comments="#", dtype=None, encoding="utf-8",
                          skip_header=_lines_before_names(path))
    assert table.dtype.names[:5] == ("time_s", "T2_K", "T5_K", "heater_W", "setpoint_K")
    assert np.allclose(table["T2_K"], record.flange_K)


def _lines_before_names(path) -> int:
    """The header's comment lines before the column names (numpy.genfromtxt's skip_header)."""
    for number, line in enumerate(path.read_text().splitlines()):
        if not line.startswith("#"):
            return number
    return 0
