"""CPU time of the data log's writer thread per row: rows as fast as it takes them (``--speed max``) and one
row at a time (service: one write per 80 ms tick), against another checkout.

Run: PYTHONPATH=. python3 benchmarks/data_log_cost.py [--tree OTHER_CHECKOUT] [--rows N]

Each tree runs in a fresh process (its own ``cryod`` on ``PYTHONPATH``) with the example configuration's
columns (24, the feedforward's included) and rows as the loop makes them. The writer thread's own CPU
time comes from ``time.thread_time`` inside it, so what the producer costs is left out; the figure is
microseconds of the writer's CPU per row, the best of three runs.

* ``batched``: N rows queued at once, written in batches (virtual time);
* ``one by one``: each row handed over and written before the next (``drain`` where the tree has it,
  otherwise a wait until the queue is empty), as in service where each tick's row is written alone.

Results: ``benchmarks/results/data_log_cost.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent

PROBE = r"""
import json, math, sys, tempfile, threading, time
from pathlib import Path
from cryod.config import load_config
from cryod.records.columns import Row
from cryod.records import datalog as datalog_module
from cryod.records.datalog import DataLog
from cryod.service.loop import daemon_schema

rows_wanted, folder = int(sys.argv[1]), Path(sys.argv[2])
config = load_config(Path(sys.argv[3]))
schema = daemon_schema(config)
control = [column.name for column in schema.columns[13:-1]]
original_run = DataLog._run
cpu = {}

def timed_run(self):
    start = time.thread_time()
    try:
        original_run(self)
    finally:
        cpu[id(self)] = time.thread_time() - start

DataLog._run = timed_run

def rows(count):
    for k in range(count):
        t = 0.08 * (k + 1)
        yield Row(time_s=t, lateness_ms=0.01, state="closed", T2_K=5.0000123 + 1e-7 * math.sin(k), T5_K=3.3412345,
                  heater_W=0.1101234, setpoint_K=5.0, T2_ohm=2754.18, T5_ohm=711.88, T2_sample_s=t + 0.01,
                  T5_sample_s=t + 0.01, heater_set_s=t + 0.05, trigger_skew_ms=0.0, cycle_ms=47.5,
                  control={name: 0.001234567 * (1 + index) for index, name in enumerate(control)})

def drained(datalog):
    if hasattr(datalog, "drain"):
        datalog.drain()
    else:
        while not datalog._queue.empty():
            time.sleep(0.0002)

def run(one_by_one):
    with tempfile.TemporaryDirectory(dir=folder) as directory:
        datalog = DataLog(Path(directory), schema, {"site": "bench"}, lambda t: 1_795_000_000.0 + t, 0.08, 2.0)
        datalog.start()
        count = rows_wanted // 20 if one_by_one else rows_wanted
        for row in rows(count):
            datalog.put(row)
            if one_by_one:
                drained(datalog)
        datalog.stop()
        return cpu[id(datalog)] / count * 1e6

datalog_module.BATCH_PAUSE_S = 0.0
print(json.dumps({"batched": min(run(False) for _ in range(3)), "one by one": min(run(True) for _ in range(3))}))
"""


def measure(tree: Path, rows: int, folder: Path) -> dict:
    environment = dict(os.environ, PYTHONPATH=str(tree))
    child = subprocess.run([sys.executable, "-c", PROBE, str(rows), str(folder),
                            str(REPOSITORY / "config" / "cryod.yaml")],
                           env=environment, capture_output=True, text=True, check=True)
    return json.loads(child.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", type=Path, default=None, help="another checkout to compare with")
    parser.add_argument("--rows", type=int, default=100_000)
    args = parser.parse_args()
    trees = [("this tree", REPOSITORY)] + ([("other tree", args.tree)] if args.tree else [])
    print("| tree | batched (us of writer CPU per row) | one by one (us per row) |")
    print("|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for name, tree in trees:
            figures = measure(tree, args.rows, Path(folder))
            print(f"| {name} | {figures['batched']:.1f} | {figures['one by one']:.1f} |")


if __name__ == "__main__":
    main()
