"""CPU time of each test of a pytest run: a pytest plugin, and a table of what it wrote.

Run: .venv/bin/python -m pytest -q -p no:cacheprovider -p benchmarks.suite_cpu [pytest's arguments]
     .venv/bin/python benchmarks/suite_cpu.py [suite-cpu.json] [--top 40]

On a shared machine a test's wall time says more about the others' load than about the test; its
CPU time (user + system of the pytest process and of the child processes it has waited for, from
the test's setup to its teardown) says what it costs. The plugin writes one row per test,
``[node id, CPU s, wall s]``, to ``suite-cpu.json`` (or the file ``CRYOD_SUITE_CPU`` names) at the end
of the session; the script prints the modules and the tests that cost most. A module's first test
also pays for the imports the module's tests share, and a process the test started but did not wait
for (a dry run it only terminated) counts when pytest's process reaps it.

Results: ``benchmarks/results/suite_cpu.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import resource
import time
from pathlib import Path

import pytest

OUTPUT = "suite-cpu.json"


def cpu_s() -> float:
    """User + system CPU of this process and of the children it has waited for (s)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


_rows: list[tuple[str, float, float]] = []


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    cpu, wall = cpu_s(), time.monotonic()
    yield
    _rows.append((item.nodeid, cpu_s() - cpu, time.monotonic() - wall))


def pytest_sessionfinish(session):
    Path(os.environ.get("CRYOD_SUITE_CPU", OUTPUT)).write_text(json.dumps(_rows))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rows", nargs="?", default=OUTPUT, help="the plugin's file (default: %(default)s)")
    parser.add_argument("--top", type=int, default=40, help="how many modules and tests to list")
    args = parser.parse_args()
    rows = json.loads(Path(args.rows).read_text())
    print(f"{len(rows)} tests: {sum(row[1] for row in rows):.1f} s of CPU, {sum(row[2] for row in rows):.1f} s of wall time")
    modules = collections.defaultdict(lambda: [0.0, 0.0, 0])
    for node, cpu, wall in rows:
        module = modules[node.split("::")[0]]
        module[0] += cpu
        module[1] += wall
        module[2] += 1
    print("\n  CPU s   wall s  tests  module")
    for name, (cpu, wall, count) in sorted(modules.items(), key=lambda item: -item[1][0])[:args.top]:
        print(f"{cpu:7.1f} {wall:8.1f} {count:6d}  {name}")
    print("\n  CPU s   wall s  test")
    for node, cpu, wall in sorted(rows, key=lambda row: -row[1])[:args.top]:
        print(f"{cpu:7.1f} {wall:8.1f}  {node}")


if __name__ == "__main__":
    main()
