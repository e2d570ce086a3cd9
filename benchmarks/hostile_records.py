"""Peak memory, time and outcome of ``cryod analyze`` on hostile files, against another checkout.

Run: PYTHONPATH=. python3 benchmarks/hostile_records.py [--tree OTHER_CHECKOUT] [--tool analyze] [--cases NAME ...]

The files are those of the adversarial run (tests/hostile_records.py: a FIFO, /dev/zero, a 300 MB header
line, a 1 MB gzip of 1 GiB of blank lines, ...). Each run is a fresh process with the tree first on
``PYTHONPATH``, its address space limited to 4 GiB (a reader that would take all the memory meets
MemoryError there instead of taking the machine's), killed after 60 s (600 s for the gzip of blank
lines). The peak is the child's own (VmHWM, tests/measured_child.py); a killed child has none.

Results: ``benchmarks/results/hostile_records.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))

from tests.hostile_records import HOSTILE_RECORDS  # noqa: E402
from tests.measured_child import run_cryod  # noqa: E402

ADDRESS_SPACE_BYTES = 4 << 30
TOOL_ARGUMENTS = {
    "analyze": lambda path, folder: ["analyze", str(path), "--out", str(folder / "analysis"), "--no-figures"],
    "identify": lambda path, folder: ["identify", str(path), "--out", str(folder / "model.yaml"), "--bootstrap", "0"],
    "plot": lambda path, folder: ["plot", str(path), "--out", str(folder / "figure.png")],
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", type=Path, default=None, help="another checkout to compare")
    parser.add_argument("--tool", choices=TOOL_ARGUMENTS, default="analyze")
    parser.add_argument("--cases", nargs="+", default=None, help="only these cases (names as in the table)")
    args = parser.parse_args()
    trees = [("this", REPOSITORY)] + ([("other", args.tree.resolve())] if args.tree else [])
    print("| file | tree | outcome | peak (MB) | wall (s) |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as temporary:
        for number, case in enumerate(HOSTILE_RECORDS):
            if args.cases and case.name not in args.cases:
                continue
            folder = Path(temporary) / f"case-{number}"
            folder.mkdir()
            path = case.make(folder)
            for name, tree in trees:
                child = run_cryod(TOOL_ARGUMENTS[args.tool](path, folder), folder, tree=tree,
                                  timeout_s=600.0 if "blank lines" in case.name else 60.0,
                                  address_space_bytes=ADDRESS_SPACE_BYTES)
                peak = "-" if child.peak_MB is None else f"{child.peak_MB:.0f}"
                outcome = child.outcome.replace(str(folder) + "/", "").replace("|", "/")
                print(f"| {case.name} | {name} | {outcome} | {peak} | {child.wall_s:.1f} |", flush=True)
            for made in folder.iterdir():
                if made.is_file():
                    made.unlink()


if __name__ == "__main__":
    main()
