"""The adversarial run over the records (slow): disk conditions while the daemon writes, hostile files given
to the offline tools. Prints its figures as markdown tables (``-s``); benchmarks/results/data_log_cost.md and docs/explanation/analysis-method.md
quote them.

    python -m pytest -m slow -s tests/test_adversarial_records.py
"""

import pytest

from tests import disk_conditions, hostile_records
from tests.measured_child import run_cryod

pytestmark = pytest.mark.slow

#: What each disk condition must end in: (exit code, the stop event in the record, rows lost; None: either, some).
DISK_OUTCOMES = {
    "record deleted": (0, True, 0),
    "record moved": (0, True, 0),
    "record replaced": (0, True, 0),
    "record overwritten": (0, True, 0),
    "directory deleted": (7, False, None),          # nowhere to write: the journal has the stop
    "directory moved": (7, True, 0),                # the moved record takes the last rows and the stop
    "disk filled": (7, True, 0),                    # the space held ahead of the record takes them
    "disk filled, no room held": (7, None, None),   # without fallocate: the rows after the disk filled are lost,
                                                    # the stop event too unless a line still fits
    "file size limit": (7, False, None),            # no byte more fits in the file
}


def test_disk_conditions_while_the_daemon_writes(tmp_path):
    print("\n| case | what | exit | files (rows) | stop event in the record | rows lost "
          "| rows from the harm to heater off (virtual time) |")
    print("|---|---|---|---|---|---|---|")
    for number, name in enumerate(disk_conditions.CASES):
        folder = tmp_path / f"case-{number}"
        folder.mkdir()
        outcome = disk_conditions.measure(name, folder)
        if "skipped" in outcome:
            print(f"| {name} | skipped: {outcome['skipped']} | | | | | |")
            continue
        exit_code, stop_recorded, lost = DISK_OUTCOMES[name]
        files = ", ".join(f"{item['file'].split('/', 1)[-1] if item['file'].startswith('data/') else item['file']} "
                          f"({item['rows']})" for item in outcome["files"]) or "none"
        print(f"| {name} | {outcome['description']} | {outcome['exit_code']} | {files} | "
              f"{'yes' if outcome['stop_event_recorded'] else 'no'} | {outcome['rows_lost']} | "
              f"{outcome['rows_from_harm_to_heater_off'] if outcome['exit_code'] else '-'} |")
        assert outcome["exit_code"] == exit_code, outcome
        if stop_recorded is not None:
            assert outcome["stop_event_recorded"] == stop_recorded, outcome
        assert outcome["heater_off_at_end_A"] == 0.0
        if lost is not None:
            assert outcome["rows_lost"] == lost, outcome
        if exit_code == 0:                        # the new file says why it exists
            assert any(item["first_event"] and "it goes on in this file" in item["first_event"]
                       for item in outcome["files"]), outcome


TOOLS = {
    "analyze": lambda path, folder: ["analyze", str(path), "--out", str(folder / "analysis"), "--no-figures"],
    "identify": lambda path, folder: ["identify", str(path), "--out", str(folder / "model.yaml"), "--bootstrap", "0"],
    "plot": lambda path, folder: ["plot", str(path), "--out", str(folder / "figure.png")],
}
#: Each tool on each hostile file: at most this peak memory (MB) and wall time (s).
MOST_PEAK_MB = 250.0
MOST_WALL_S = 60.0


def test_hostile_records_given_to_the_tools(tmp_path):
    print("\n| file | tool | outcome | peak (MB) | wall (s) |")
    print("|---|---|---|---|---|")
    for number, case in enumerate(hostile_records.HOSTILE_RECORDS):
        folder = tmp_path / f"case-{number}"
        folder.mkdir()
        path = case.make(folder)
        for tool, arguments in TOOLS.items():
            child = run_cryod(arguments(path, folder), folder, timeout_s=3 * MOST_WALL_S)
            print(f"| {case.name} | {tool} | {child.outcome.replace(str(folder) + '/', '')} | "
                  f"{child.peak_MB:.0f} | {child.wall_s:.1f} |" if child.peak_MB is not None else
                  f"| {case.name} | {tool} | {child.outcome} | - | {child.wall_s:.1f} |")
            assert child.status is not None and "Traceback" not in child.stderr, (case.name, tool, child.stderr)
            if not case.read:
                assert child.status == 2 and f"{path}" in child.stderr and case.says in child.stderr, \
                    (case.name, tool, child.stderr)
            assert child.peak_MB < MOST_PEAK_MB and child.wall_s < MOST_WALL_S, (case.name, tool, child)
        for made in folder.iterdir():
            if made.is_file() and made.stat().st_size > 100e6:
                made.unlink()                     # the 300 MB files, before the next case adds its own
