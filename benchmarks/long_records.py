"""Wall time, CPU time and peak resident memory of reading, ``cryod analyze`` and ``cryod identify``
on long records, against another checkout.

Run: PYTHONPATH=. python3 benchmarks/long_records.py RECORD [RECORD ...] [--tree OTHER_CHECKOUT]
     PYTHONPATH=. python3 benchmarks/long_records.py --make 3600 30000 --folder DIR [--tree ...]

``--make S ...`` first writes daemon records of S simulated seconds each into DIR
(``cryod --simulate --duration S --speed max``: 12.5 Hz, 24 columns, about 12.5 MB per hour).
Each step is a fresh process (``python -m cryod.cli ...`` or a reading probe) with the tree on
``PYTHONPATH``; its CPU time (user + system) and peak resident set come from ``os.wait4``, so they
are the child's own, whatever else the machine runs. Steps:

* ``read``: ``read_record(path)``, every column;
* ``read analysed``: what the commands read (``read_record_data``: the analysis's columns; the
  other tree: ``read_record`` and ``RecordData.from_record``, as its commands did);
* ``analyze``: ``cryod analyze RECORD --json`` with its figures, report and model file, as a user runs it;
* ``analyze whole``: the same with ``--max-duration 0`` (the whole record; this tree only: the other
  analysed every record whole);
* ``identify``: ``cryod identify RECORD --out ... --json``.

Printed: one markdown row per record, tree and step. The machine is shared: CPU time is the
figure to compare; wall time is what a user waited on that run.

Results: ``benchmarks/results/long_records.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent

READ_PROBE = r"""
import sys
from cryod.records.record import read_record
read_record(sys.argv[1])
"""

READ_ANALYSED_PROBE = r"""
import sys
try:
    from cryod.analysis.record_data import read_record_data
except ImportError:
    from cryod.analysis.record_data import RecordData
    from cryod.records.record import read_record
    read_record_data = lambda path: RecordData.from_record(read_record(path))
read_record_data(sys.argv[1])
"""


def run_measured(arguments: list[str], tree: Path, cwd: Path) -> dict:
    """Run a child process; its wall time, CPU time and peak resident set."""
    environment = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg")
    started = time.perf_counter()
    child = subprocess.Popen(arguments, cwd=cwd, env=environment, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE)
    stderr = child.stderr.read()
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - started
    if child.returncode != 0:
        raise RuntimeError(f"{' '.join(arguments)} failed ({child.returncode}): {stderr.decode()[-400:]}")
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "peak_rss_MB": usage.ru_maxrss / 1024.0}


def make_record(seconds: float, folder: Path) -> Path:
    """A daemon record of ``seconds`` simulated seconds (the daemon on the simulated cryostat)."""
    data = folder / f"simulated-{seconds:.0f}s"
    output = subprocess.run(
        [sys.executable, "-m", "cryod.cli", "--simulate", "--duration", str(seconds), "--speed", "max", "--json",
         "--data-dir", str(data), "--socket", str(folder / f"c-{seconds:.0f}.sock"), "--transport", "in-process"],
        capture_output=True, text=True, check=True, cwd=folder,
        env=dict(os.environ, PYTHONPATH=str(REPOSITORY)))
    path = Path(json.loads(output.stdout)["log_path"])
    return path.rename(folder / f"record-{seconds:.0f}s.csv")


def record_hours(path: Path) -> float:
    """Duration of a record (h), from its last data line."""
    with path.open("rb") as stream:
        stream.seek(max(path.stat().st_size - 4096, 0))
        lines = [line for line in stream.read().decode("utf-8", "replace").splitlines()
                 if line and not line.startswith("#")]
    return float(lines[-1].split(",")[0]) / 3600.0


def steps(record: Path, work: Path) -> dict[str, list[str]]:
    python = sys.executable
    return {
        "read": [python, "-c", READ_PROBE, str(record)],
        "read analysed": [python, "-c", READ_ANALYSED_PROBE, str(record)],
        "analyze": [python, "-m", "cryod.cli", "analyze", str(record), "--json", "--out", str(work / "analysis")],
        "analyze whole": [python, "-m", "cryod.cli", "analyze", str(record), "--json", "--max-duration", "0",
                          "--out", str(work / "analysis-whole")],
        "identify": [python, "-m", "cryod.cli", "identify", str(record), "--json", "--force",
                     "--out", str(work / "identified.yaml")],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("records", nargs="*", type=Path)
    parser.add_argument("--make", nargs="+", type=float, default=(), metavar="S",
                        help="first make daemon records of these simulated durations (s)")
    parser.add_argument("--folder", type=Path, default=None, help="where --make writes (default: a temporary one)")
    parser.add_argument("--tree", type=Path, default=None, help="another checkout to compare")
    parser.add_argument("--steps", nargs="+", default=("read", "read analysed", "analyze", "analyze whole", "identify"))
    args = parser.parse_args()
    trees = [("this", REPOSITORY)] + ([("other", args.tree.resolve())] if args.tree else [])
    with tempfile.TemporaryDirectory() as temporary:
        folder = (args.folder or Path(temporary)).resolve()
        folder.mkdir(parents=True, exist_ok=True)
        records = [make_record(seconds, folder) for seconds in args.make] + [path.resolve() for path in args.records]
        print("| record | size (MB) | hours | tree | step | wall (s) | CPU (s) | peak resident (MB) |")
        print("|---|---|---|---|---|---|---|---|")
        for record in records:
            size, hours = record.stat().st_size / 1e6, record_hours(record)
            for step in args.steps:
                for name, tree in trees:
                    if step == "analyze whole" and name != "this":
                        continue
                    work = Path(temporary) / f"{name}-{record.stem}"
                    work.mkdir(exist_ok=True)
                    measured = run_measured(steps(record, work)[step], tree, Path(temporary))
                    print(f"| {record.name} | {size:.1f} | {hours:.2f} | {name} | {step} | {measured['wall_s']:.1f} "
                          f"| {measured['cpu_s']:.1f} | {measured['peak_rss_MB']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
