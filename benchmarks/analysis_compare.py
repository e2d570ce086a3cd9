"""Two runs of ``benchmarks/analysis_causes.py`` compared record by record: the same analyses, or what differs.

Run: PYTHONPATH=. python3 benchmarks/analysis_compare.py FIRST.json SECOND.json [--outputs FIRST_DIR SECOND_DIR]

Each run's ``--json`` results are compared record by record, every key but
the times (``wall_s``, ``cpu_s``) and the outputs' directory; with
``--outputs``, each record's ``cryod analyze`` outputs (``analysis.json``,
``report.md``, the extended model, written by ``--outputs``) are compared as
text, with each run's directory written ``DIR`` and the seconds of the
report's timing table left out (the steps' names and order are kept). The
runs are typically the same plan on two checkouts' code::

    PYTHONPATH=. python3 benchmarks/analysis_causes.py --json this.json --outputs this
    PYTHONPATH=OTHER_CHECKOUT python3 benchmarks/analysis_causes.py --json other.json --outputs other
    PYTHONPATH=. python3 benchmarks/analysis_compare.py this.json other.json --outputs this other

Printed: one line per record that differs (which key or file, and for the
``--json`` objects the largest relative difference of a number), then a
count; the exit status is 1 when anything differs. A record whose columns
differ (``record.sha256``: the daemon's own records are made afresh in each
run) is said to be so: its analysis then need not agree.

Results: ``benchmarks/results/analysis_causes.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from analysis_speed import json_differences

#: Result keys that differ from run to run whatever the analysis does.
NOT_COMPARED = ("wall_s", "cpu_s", "outputs")
#: The files of a record's outputs that are compared.
OUTPUT_FILES = ("record.sha256", "analysis.json", "report.md", "extended-model.yaml")
#: A row of the report's timing table: its seconds are left out.
TIMING_ROW = re.compile(r"^(\| [^|]+ \| )[0-9.]+( \|)$", re.MULTILINE)


def _canonical(value) -> str:
    """One spelling of a JSON value (NaN equals NaN in it)."""
    return json.dumps(value, sort_keys=True)


def results_by_record(path: Path) -> dict[int, dict]:
    return {result["index"]: {key: value for key, value in result.items() if key not in NOT_COMPARED}
            for result in json.loads(path.read_text(encoding="utf-8"))}


def comparable_text(path: Path, run_directory: Path) -> str | None:
    """A file's text with its run's directory written ``DIR`` and the report's seconds left out (None: absent)."""
    if not path.exists():
        return None
    text = path.read_text(encoding="utf-8").replace(str(run_directory.resolve()), "DIR")
    return TIMING_ROW.sub(r"\1s\2", text) if path.name == "report.md" else text


def output_differences(index: int, first: Path, second: Path) -> list[str]:
    """What differs in one record's outputs between two runs' directories."""
    found = []
    for name in OUTPUT_FILES:
        texts = [comparable_text(run / f"record-{index:03d}" / name, run) for run in (first, second)]
        if texts[0] == texts[1]:
            continue
        if name == "analysis.json" and None not in texts:
            largest, where = json_differences(*(json.loads(text) for text in texts))
            found.append(f"{name}: largest relative difference {largest:.3g}"
                         + (f", differ: {where[:5]}" if where else ""))
        else:
            found.append(name + (" (the records' columns differ)" if name == "record.sha256" else ""))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", type=Path, help="one run's --json results")
    parser.add_argument("second", type=Path, help="the other run's")
    parser.add_argument("--outputs", nargs=2, type=Path, metavar=("FIRST_DIR", "SECOND_DIR"),
                        help="the two runs' --outputs directories")
    args = parser.parse_args()
    first, second = results_by_record(args.first), results_by_record(args.second)
    differing = 0
    for index in sorted(set(first) | set(second)):
        if index not in first or index not in second:
            print(f"record {index}: only in {args.first if index in first else args.second}")
            differing += 1
            continue
        found = []
        if _canonical(first[index]) != _canonical(second[index]):
            keys = [key for key in sorted(set(first[index]) | set(second[index]))
                    if _canonical(first[index].get(key)) != _canonical(second[index].get(key))]
            largest, _ = json_differences(first[index], second[index])
            found.append(f"results differ in {', '.join(keys)} (largest relative difference of a number "
                         f"{largest:.3g})")
        if args.outputs:
            found += output_differences(index, *args.outputs)
        if found:
            print(f"record {index}: " + "; ".join(found))
            differing += 1
    print(f"{len(set(first) | set(second))} records compared"
          + (" with their cryod analyze outputs" if args.outputs else "") + f": {differing} differ")
    sys.exit(1 if differing else 0)


if __name__ == "__main__":
    main()
