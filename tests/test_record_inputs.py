"""Files that are not records are refused before they are opened, and records beyond the bounds as they
stream in: in bounded memory and time, with the file, the line and the bound named."""

import gzip
import os
import resource
import subprocess
import sys
import threading
import tracemalloc

import pytest

from cryod import cli
from cryod.records import bounds, data_lines
from cryod.records.record import RecordFormatError, read_record
from tests import hostile_records
from tests.conftest import REPOSITORY
from tests.hostile_records import HEADER, ROW


def _refusal(path) -> RecordFormatError:
    """The error reading ``path`` gives, on a thread so that a reader that waits fails the test instead of
    hanging it."""
    outcome = {}

    def read():
        try:
            read_record(path)
        except RecordFormatError as error:
            outcome["error"] = error

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(60.0)
    assert not reader.is_alive(), f"reading {path} did not return"
    assert "error" in outcome, f"{path} was read as a record"
    return outcome["error"]


@pytest.mark.parametrize("make, what", [(hostile_records.fifo, "is a FIFO (named pipe), not a regular file"),
                                        (hostile_records.directory, "is a directory, not a regular file"),
                                        (hostile_records.unix_socket, "is a socket, not a regular file")])
def test_a_special_file_is_refused_before_it_is_opened(tmp_path, make, what):
    path = make(tmp_path)
    error = _refusal(path)
    assert str(error) == f"{path}: {what}: a record must be a regular file"


def test_a_fifo_given_to_the_tools_is_refused_with_exit_2(tmp_path, capsys):
    path = hostile_records.fifo(tmp_path)
    arguments = {"analyze": [str(path), "--out", str(tmp_path / "analysis")],
                 "identify": [str(path), "--out", str(tmp_path / "model.yaml")],
                 "plot": [str(path), "--out", str(tmp_path / "figure.png")]}
    for tool, rest in arguments.items():
        outcome = {}
        runner = threading.Thread(target=lambda: outcome.setdefault("status", cli.main([tool, *rest])), daemon=True)
        runner.start()
        runner.join(60.0)
        assert not runner.is_alive(), f"cryod {tool} waited on a FIFO"
        assert outcome["status"] == 2
        assert f"{path}: is a FIFO (named pipe), not a regular file" in capsys.readouterr().err
    assert not (tmp_path / "analysis").exists() and not (tmp_path / "model.yaml").exists()


@pytest.mark.parametrize("make", [hostile_records.dev_zero, hostile_records.sparse_file])
def test_an_endless_or_enormous_file_is_refused_at_once_in_a_process_with_little_memory(tmp_path, make):
    """/dev/zero never ends and a 9 GiB hole is one line of NULs: both refused before a byte is read (the
    child may use at most 1.5 GB, so a reader that holds the text fails with MemoryError instead)."""
    path = make(tmp_path)

    def limit_memory():
        resource.setrlimit(resource.RLIMIT_AS, (1536 << 20, 1536 << 20))

    child = subprocess.run([sys.executable, "-m", "cryod.cli", "plot", str(path), "--out", str(tmp_path / "f.png")],
                           cwd=REPOSITORY, capture_output=True, text=True, timeout=300, preexec_fn=limit_memory,
                           env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
    assert child.returncode == 2, child.stderr[-2000:]
    assert child.stderr.startswith(f"cryod plot: {path}: ") and "Traceback" not in child.stderr
    assert ("is a character device" in child.stderr if path.name == "zero"
            else "GB, more than the 8 GiB a record may have" in child.stderr)


def _peak_reading(path) -> tuple[RecordFormatError, int]:
    tracemalloc.start()
    try:
        with pytest.raises(RecordFormatError) as caught:
            read_record(path)
        return caught.value, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_header_line_beyond_its_bound_is_refused_having_read_no_more_than_the_bound(tmp_path):
    path = hostile_records.long_header_line(tmp_path, characters=8 << 20)
    error, peak = _peak_reading(path)
    assert (error.source, error.line) == (str(path), 2)
    assert error.reason.startswith("header line longer than 1 MiB, the most a record's header line may have")
    assert peak < 4 * bounds.MAX_HEADER_LINE_CHARACTERS + (1 << 20)       # not the 8 MiB line


def test_a_data_line_beyond_its_bound_is_refused_with_its_line(tmp_path):
    path = hostile_records.long_data_line(tmp_path, characters=1 << 20)
    error, _ = _peak_reading(path)
    assert (error.line, error.reason.split(",")[0]) == (3, "longer than 64 KiB")


def test_more_columns_than_the_bound_are_refused(tmp_path):
    error, _ = _peak_reading(hostile_records.many_columns(tmp_path, count=1000))
    assert error.line == 2 and error.reason.startswith("1005 columns, more than the 1000 a record may have")


def test_more_lines_than_the_bound_are_refused_also_when_they_are_blank_and_compressed(tmp_path, monkeypatch):
    monkeypatch.setattr(data_lines, "MAX_LINES", 5000)
    path = hostile_records.gzip_of_blank_lines(tmp_path, blank_bytes=10_000)
    error, _ = _peak_reading(path)
    assert error.line == 5001 and error.reason.startswith("more than 5000 lines, the most a record may have")
    fewer = tmp_path / "fewer"
    fewer.mkdir()
    assert len(read_record(hostile_records.gzip_of_blank_lines(fewer, blank_bytes=4000))) == 1


def test_more_text_than_the_bound_is_refused_while_decompressing(tmp_path, monkeypatch):
    monkeypatch.setattr(data_lines, "MAX_TEXT_CHARACTERS", 100_000)
    path = tmp_path / "long.csv.gz"
    rows = "".join(f"{0.08 * (index + 1):.4f},4.23,3.34,0,\n" for index in range(10_000))
    path.write_bytes(gzip.compress((HEADER + rows).encode()))
    error, _ = _peak_reading(path)
    assert error.reason.startswith("the text goes on for more than 100000 characters, the most a record may have")


def test_more_event_text_than_the_bound_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(data_lines, "MAX_EVENT_CHARACTERS", 10_000)
    path = tmp_path / "events.csv"
    path.write_text(HEADER + ROW + "# event: note: a storm of notes\n" * 1000, encoding="utf-8")
    error, _ = _peak_reading(path)
    assert error.reason.startswith("more than 10000 characters of event lines")


def test_a_cut_short_compressed_record_gives_its_rows_up_to_the_cut(tmp_path):
    record = read_record(hostile_records.truncated_gzip(tmp_path, rows=20_000))
    assert 1000 < len(record) < 20_000
    assert record.time_s[-1] == pytest.approx(0.08 * len(record))          # every row up to the cut, in order
    assert record.warnings[0].startswith("the compressed file is cut short")


def test_a_record_within_the_bounds_is_read_whole(tmp_path):
    path = tmp_path / "record.csv"
    path.write_text(HEADER.replace("\n", "\n# site: " + "x" * 100_000 + "\n", 1) + ROW * 1 + "# event: note\n",
                    encoding="utf-8")
    record = read_record(path)
    assert len(record) == 1 and len(record.metadata["site"]) == 100_000 and record.events == [(1, "event: note")]
