"""What others do to the data log's disk while the daemon regulates, one case per process.

Run: python -m tests.disk_conditions CASE FOLDER      (prints the outcome as one JSON object)

The whole daemon runs on the simulated cryostat and virtual time (as tests/test_daemon_faults.py) for
300 s with its record in FOLDER/data; at row :data:`ACTION_ROW` the case does its harm from the loop's
thread, as another program would. The outcome says how the daemon ended, which files hold the record,
whether the stop event is in one of them, and how many of the rows the loop made are in no file (of
those made after the harm, where the harm itself deleted the rows written before it). On virtual time the loop runs ahead of the writer (a few hundred rows), so rows counted from
the harm to the heater's stop include that lead; in service the writer takes each row as it comes.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from cryod.records import record_file
from cryod.records.record import RecordFormatError, read_record
from drivers.clock import VirtualClock
from cryod.service.daemon import Daemon
from cryod.service.notify import SystemdNotifier
from tests.fault_drills import FaultDrill

ACTION_ROW = 1500
DURATION_S = 300.0
#: The small disk of the cases that fill it (a tmpfs: needs the right to mount one).
SMALL_DISK = "16m"


def _fill(folder: Path) -> None:
    """Write into ``folder`` until the disk is full, as another program would."""
    with open(folder / "filler.bin", "wb", buffering=0) as filler:
        try:
            while True:
                filler.write(b"x" * 65536)
        except OSError:
            pass
        try:
            while True:
                filler.write(b"x" * 512)
        except OSError:
            pass


def _remove(data: Path) -> None:
    """``rm -rf``, again if the daemon put a new file in meanwhile."""
    while data.exists():
        shutil.rmtree(data, ignore_errors=True)


def _record(data: Path) -> Path:
    return next(data.glob("cryod-*.csv"))


@dataclass(frozen=True)
class DiskCondition:
    """One case: what it stands for, the harm done at ACTION_ROW given (data directory, case folder) (None: the
    case's limit does the harm), whether the harm itself deletes rows already written (then only the rows made
    after it count as lost), whether it needs a tmpfs."""

    description: str
    harm: Callable[[Path, Path], object] | None
    deletes_rows: bool = False
    small_disk: bool = False


CASES = {
    "record deleted": DiskCondition("rm of the record being written", lambda data, folder: _record(data).unlink(),
                                    deletes_rows=True),
    "record moved": DiskCondition("mv of the record to another name",
                                  lambda data, folder: _record(data).rename(data / "kept-aside.csv")),
    "record replaced": DiskCondition("mv of another file onto the record",
                                     lambda data, folder: os.replace(_other(folder), _record(data)), deletes_rows=True),
    "record overwritten": DiskCondition("cp of another file over the record (the same file, truncated)",
                                        lambda data, folder: shutil.copyfile(_other(folder), _record(data)),
                                        deletes_rows=True),
    "directory deleted": DiskCondition("rm -rf of the data directory", lambda data, folder: _remove(data),
                                       deletes_rows=True),
    "directory moved": DiskCondition("mv of the data directory", lambda data, folder: data.rename(folder / "moved")),
    "disk filled": DiskCondition("another program fills the disk (16 MB tmpfs)", lambda data, folder: _fill(data),
                                 small_disk=True),
    "disk filled, no room held": DiskCondition("the same on a file system without fallocate",
                                               lambda data, folder: _fill(data), small_disk=True),
    "file size limit": DiskCondition("RLIMIT_FSIZE of 400 kB reached (about row 1800)", None),
}


def _other(folder: Path) -> Path:
    other = folder / "other.csv"
    other.write_text("another program's file\n")
    return other


def _mount_small_disk(data: Path) -> bool:
    data.mkdir(parents=True)
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={SMALL_DISK}", "tmpfs", str(data)],
                          capture_output=True).returncode == 0


def _files(folder: Path) -> list[Path]:
    return sorted(path for path in folder.rglob("cryod-*.csv*")) + sorted(folder.rglob("kept-aside.csv"))


def _row_indices(path: Path, wall_zero_s: float, period_s: float) -> list[int]:
    """The rows of a file as tick numbers (from their wall time: the file's start plus time_s)."""
    record = read_record(path)
    start = dt.datetime.fromisoformat(record.metadata["record_start_utc"]).timestamp()
    return [round((start + t - wall_zero_s) / period_s) for t in record.time_s.tolist()]


def run_case(name: str, folder: Path) -> dict:
    """Run one case in ``folder``; its outcome."""
    case = CASES[name]
    description, harm, small_disk = case.description, case.harm, case.small_disk
    folder = Path(folder)
    data = folder / "data"
    if small_disk and not _mount_small_disk(data):
        return {"case": name, "skipped": "no right to mount a tmpfs here"}
    if name == "disk filled, no room held":
        record_file._FALLOCATE = None
    if name == "file size limit":
        resource.setrlimit(resource.RLIMIT_FSIZE, (400_000, 400_000))
    try:
        drill = FaultDrill(folder, {ACTION_ROW: (lambda bench: harm(data, folder))} if harm else {})
        config = drill.config
        config = dataclasses.replace(config, data=dataclasses.replace(config.data, min_free_MB=1.0, warn_free_MB=2.0,
                                                                      compress_finished=False))
        daemon = Daemon(config, drill.open_instruments, VirtualClock(), notifier=SystemdNotifier({}),
                        row_taps=[drill.tap], install_signal_handlers=False)
        started = time.perf_counter()
        result = daemon.run(DURATION_S)
        wall_s = time.perf_counter() - started
        period = config.loop.period_s
        wall_zero = daemon.datalog.monotonic_to_wall(0.0)
        made = [round((daemon.datalog.monotonic_to_wall(row.time_s) - wall_zero) / period) for row in drill.rows]
        files, recorded, stop_recorded, unreadable = [], set(), False, []
        for path in _files(folder):
            try:
                indices = _row_indices(path, wall_zero, period)
                events = [text for _, text in read_record(path).events]
            except RecordFormatError as error:
                unreadable.append(str(error))
                continue
            files.append({"file": str(path.relative_to(folder)), "rows": len(indices),
                          "first_event": next((text for text in events if "disk:" in text), None)})
            recorded.update(indices)
            stop_recorded |= any(text.startswith("event: stop:") for text in events)
        counted = made[ACTION_ROW:] if case.deletes_rows else made
        lost = [index for index in counted if index not in recorded]
        harm_row = ACTION_ROW if harm else made.index(lost[0]) if lost else None
        off = next((number for number, row in enumerate(drill.rows) if row.state.startswith("fault:")), None)
        fault = result.loop.last_fault if result.loop is not None else None
        return {"case": name, "description": description, "exit_code": int(result.exit_code),
                "fault": f"{fault.cause}: {fault.message}" if fault else None, "files": files,
                "unreadable": unreadable, "stop_event_recorded": stop_recorded,
                "rows_made": len(made), "rows_lost": len(lost),
                "rows_from_harm_to_heater_off": None if off is None or harm_row is None else off - harm_row,
                "heater_off_at_end_A": drill.supply_current_a(), "wall_s": round(wall_s, 2)}
    finally:
        if small_disk:
            subprocess.run(["umount", "--lazy", str(data)], capture_output=True)


def measure(name: str, folder: Path, timeout_s: float = 300.0) -> dict:
    """Run one case in a process of its own (limits and mounts stay there); its outcome."""
    child = subprocess.run([sys.executable, "-m", "tests.disk_conditions", name, str(folder)],
                           cwd=Path(__file__).resolve().parent.parent, capture_output=True, text=True,
                           timeout=timeout_s)
    if child.returncode != 0:
        raise RuntimeError(f"{name}: exit {child.returncode}: {child.stderr[-2000:]}")
    return json.loads(child.stdout.splitlines()[-1])


if __name__ == "__main__":
    import logging

    logging.basicConfig(level=logging.CRITICAL)
    print(json.dumps(run_case(sys.argv[1], Path(sys.argv[2]))))
