"""The data log against what others do to its disk: the record deleted, moved, replaced or overwritten, the
directory deleted or moved, the disk filled by another program, a write that fails. No row already
recorded is lost or damaged, the record goes on in a new file (never an existing one) or the log fails at
once, and the stop event still goes into the record."""

import errno
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cryod.records.columns import Event
from cryod.records.datalog import DataLog
from cryod.records.record import read_record
from tests.conftest import REPOSITORY
from tests.record_rows import SCHEMA, rows

WALL_START = 1_795_000_000.0          # 2026-11-18 UTC, mid-day
DAY = "cryod-2026-11-18"


class Failures(list):
    """on_failure: the reasons given."""

    def __call__(self, reason):
        self.append(reason)


def _data_log(directory, **options) -> tuple[DataLog, Failures]:
    failures = Failures()
    datalog = DataLog(directory, SCHEMA, {"site": "test"}, lambda t: WALL_START + t, 0.08, 0.5,
                      on_failure=failures, **options)
    datalog.start()
    return datalog, failures


def _write(datalog, first_row, count):
    for row in rows(0.08 * first_row, count):
        datalog.put(row)
    assert datalog.drain()


def _times(path) -> np.ndarray:
    """The rows of a file by their clock time (time_s + the file's origin, from its record_start_utc)."""
    record = read_record(path)
    start = np.datetime64(record.metadata["record_start_utc"].replace("+00:00", ""), "ms")
    origin_s = (start - np.datetime64(int(WALL_START * 1000), "ms")) / np.timedelta64(1, "s")
    return np.round((record.time_s + origin_s) / 0.08).astype(int)


def test_a_deleted_record_goes_on_in_a_new_file_with_every_row_since(tmp_path, caplog):
    datalog, failures = _data_log(tmp_path)
    _write(datalog, 1, 100)
    first = tmp_path / f"{DAY}.csv"
    first.unlink()
    _write(datalog, 101, 100)
    datalog.stop()
    second = tmp_path / f"{DAY}.2.csv"
    assert datalog.paths == [first, second] and failures == []
    kept = _times(second)
    assert kept.tolist() == list(range(kept[0], 201)) and kept[0] <= 101          # every row since, once
    event = read_record(second).events[0][1]
    assert event.startswith(f"event: disk: the record's file {first} was deleted; it goes on in this file")
    assert any("was deleted" in record.message and record.levelno == logging.WARNING for record in caplog.records)


def test_rows_written_into_a_file_deleted_just_before_the_stop_are_kept(tmp_path):
    datalog, failures = _data_log(tmp_path)
    _write(datalog, 1, 100)
    (tmp_path / f"{DAY}.csv").unlink()
    datalog.stop()                                   # no row after the deletion: the last look finds it
    kept = _times(tmp_path / f"{DAY}.2.csv")          # the last write, which went into it
    assert kept.tolist() == list(range(kept[0], 101)) and failures == []


def test_a_moved_record_keeps_its_rows_and_says_where_the_record_goes_on(tmp_path):
    datalog, failures = _data_log(tmp_path)
    _write(datalog, 1, 100)
    moved = tmp_path / "kept-aside.csv"
    (tmp_path / f"{DAY}.csv").rename(moved)
    _write(datalog, 101, 100)                        # the path is looked at once a second of rows (12.5 rows)
    datalog.stop()
    second = tmp_path / f"{DAY}.2.csv"
    before, after = _times(moved), _times(second)
    assert np.concatenate([before, after]).tolist() == list(range(1, 201))   # every row, once
    assert 100 <= before[-1] <= 114
    assert read_record(moved).events[-1][1] == f"event: disk: this file was moved away from its path; the record " \
                                               f"goes on in {second.name}"
    assert "was moved away from its path" in read_record(second).events[0][1]


def test_a_record_replaced_or_overwritten_by_another_file_is_left_alone_and_none_of_its_rows_lost(tmp_path):
    datalog, failures = _data_log(tmp_path)
    _write(datalog, 1, 100)
    first = tmp_path / f"{DAY}.csv"
    other = tmp_path / "other.csv"
    other.write_text("someone else's notes\n")
    shutil.copyfile(other, first)                   # cp over it: the same file, truncated and rewritten
    _write(datalog, 101, 50)
    third = tmp_path / "third.csv"
    third.write_text("a third file\n")
    os.replace(third, tmp_path / f"{DAY}.2.csv")     # mv over the second: another file at its path
    _write(datalog, 151, 50)
    datalog.stop()
    assert first.read_text() == "someone else's notes\n"          # never written again
    assert (tmp_path / f"{DAY}.2.csv").read_text() == "a third file\n"
    assert [path.name for path in datalog.paths] == [f"{DAY}.csv", f"{DAY}.2.csv", f"{DAY}.3.csv"]
    fourth = datalog.paths[2]
    assert (tmp_path / f"{DAY}.2.csv").read_text() == "a third file\n"      # the other file at that path
    assert "was deleted" in read_record(fourth).events[0][1]                 # its path now holds another file
    kept = _times(fourth)
    assert kept[-1] == 200 and kept.tolist() == list(range(kept[0], 201)) and kept[0] <= 151


def test_a_deleted_data_directory_fails_the_log_at_the_next_write(tmp_path):
    directory = tmp_path / "data"
    datalog, failures = _data_log(directory)
    _write(datalog, 1, 100)
    shutil.rmtree(directory)
    datalog.put(rows(8.08, 1)[0])
    assert datalog.drain()
    assert failures == [f"data.directory {directory} is gone (deleted or moved)"]
    datalog.stop()
    assert not directory.exists()                   # not made again


def test_a_moved_data_directory_fails_the_log_and_the_moved_record_takes_the_last_rows_and_the_stop(tmp_path):
    directory = tmp_path / "data"
    datalog, failures = _data_log(directory)
    _write(datalog, 1, 100)
    directory.rename(tmp_path / "moved")
    _write(datalog, 101, 20)
    assert failures == [f"data.directory {directory} is gone (deleted or moved)"]
    datalog.put(Event("stop", "data_log_failed: ... (exit 7)"))
    datalog.stop()
    record = read_record(tmp_path / "moved" / f"{DAY}.csv")
    assert len(record) == 120 and record.events[-1][1] == "event: stop: data_log_failed: ... (exit 7)"


FILE_SIZE_LIMITED = """
import resource, sys
from pathlib import Path
from cryod.records.datalog import DataLog
from tests.conftest import REPOSITORY
from tests.record_rows import SCHEMA, rows
resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))
failures = []
datalog = DataLog(Path(sys.argv[1]), SCHEMA, {}, lambda t: 1_795_000_000.0 + t, 0.08, 0.5,
                  on_failure=failures.append)
datalog.start()
for row in rows(0.08, 1000):
    datalog.put(row)
datalog.stop()
print(failures)
"""


@pytest.mark.system
def test_a_write_that_fails_leaves_no_half_line_and_the_rows_before_it_untouched(tmp_path):
    """A file size limit (RLIMIT_FSIZE, 20 kB) reached inside a write: the write is cut back to where it began."""
    child = subprocess.run([sys.executable, "-c", FILE_SIZE_LIMITED, str(tmp_path)], cwd=REPOSITORY,
                           capture_output=True, text=True, timeout=120)
    path = tmp_path / f"{DAY}.csv"
    assert child.returncode == 0, child.stderr
    assert child.stdout.strip() == repr([f"writing {path} failed: File too large"])
    text = path.read_bytes()
    assert text.endswith(b"\n") and len(text) <= 20_000
    record = read_record(path)
    assert record.warnings == [] and _times(path).tolist() == list(range(1, len(record) + 1))


def _mounted_tmpfs(folder, size) -> bool:
    folder.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                             capture_output=True)
    return mounted.returncode == 0


@pytest.mark.system
def test_a_disk_filled_by_another_program_still_takes_the_last_rows_and_the_stop_event(tmp_path):
    """A 4 MB tmpfs filled to the last byte by another writer: the log fails while the space it holds ahead of
    its record takes the rows that follow and the stop event (needs the right to mount a tmpfs)."""
    disk = tmp_path / "disk"
    if not _mounted_tmpfs(disk, "4m"):
        pytest.skip("no right to mount a tmpfs here")
    datalog = None
    try:
        datalog, failures = _data_log(disk, min_free_bytes=100_000)
        _write(datalog, 1, 100)
        with open(disk / "filler", "wb", buffering=0) as filler, pytest.raises(OSError) as full:
            while True:
                filler.write(b"x" * 4096)
        assert full.value.errno == errno.ENOSPC
        _write(datalog, 101, 50)                     # the free space check finds the disk full
        assert failures == [f"only 0 MB free for {disk}, below data.min_free_MB 0.1 MB"]
        datalog.put(Event("stop", "data_log_failed: the disk is full (exit 7)"))
        datalog.stop()
        record = read_record(disk / f"{DAY}.csv")
        assert record.time_s.size == 150 and record.warnings == []
        assert [text for _, text in record.events][-2:] == [f"event: disk: {failures[0]}: stopping",
                                                          "event: stop: data_log_failed: the disk is full (exit 7)"]
        assert os.stat(disk / f"{DAY}.csv").st_blocks * 512 < os.path.getsize(disk / f"{DAY}.csv") + 8192
    finally:
        if datalog is not None:
            datalog.stop()
        subprocess.run(["umount", "--lazy", str(disk)], check=False)


def test_a_record_deleted_between_the_look_at_the_file_and_the_look_at_its_path_is_called_deleted(tmp_path,
                                                                                                 monkeypatch):
    """The open file is looked at first, then its path: a deletion that falls between the two is still a
    deletion (the open file says so), not a move."""
    from types import SimpleNamespace

    from cryod.records import record_file as module
    path = tmp_path / "cryod-2026-11-25.csv"
    record = module.RecordFile(path)
    record.write(b"# cryod-log v1\n")

    def deleted_meanwhile(looked_at):     # the record's own file, and nothing else, goes just before the look
        if Path(looked_at) == path:
            path.unlink()
        return os.stat(looked_at)

    monkeypatch.setattr(module, "os", SimpleNamespace(fstat=os.fstat, stat=deleted_meanwhile))
    assert record.check(at_path=True) == "deleted"
