"""CPU time of the loop's own thread per tick, with and without the feedforward, against another checkout.

Run: PYTHONPATH=. python3 benchmarks/loop_cpu.py [--tree OTHER_CHECKOUT] [--repeat 3] [--duration 1800]

Each measurement is a fresh process running `cryod --simulate --speed max --duration D` in process
(drivers, simulated instruments, loop, data log), with the CPU time of the thread that runs
`ControlLoop.run` taken from its start to its end (`time.thread_time`): what the 80 ms cycle itself
costs, without the data log's writer, the feedforward's learning worker or start-up. Modes:

* ``pi``: the regulator with the PI term only (the feedforward term taken out of the factory);
* ``ff-off``: the feedforward term present but switched off (`--no-feedforward`);
* ``ff``: the default, PI and the feedforward;
* ``other``: ``--tree``'s checkout (the baseline to compare with) as it is.

The modes run in turn, ``--repeat`` rounds, and the best of each is reported with its ratio to the
best ``pi`` (the machine's speed varies from run to run, so the best is the fairest figure).

Results: ``benchmarks/results/loop_cpu.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent

PROBE = r"""
import contextlib, json, os, sys, time
sys.path.insert(0, TREE)
if MODE == "pi":
    from cryod.control import terms
    terms.TERM_TYPES.pop("feedforward"); terms.term_type.cache_clear()
try:
    from cryod.service import loop as loop_module
except ImportError:
    from cryod import loop as loop_module
measured = {}
run = loop_module.ControlLoop.run
def timed(self, *args, **kwargs):
    start = time.thread_time()
    try:
        return run(self, *args, **kwargs)
    finally:
        measured["cpu_s"] = time.thread_time() - start
        measured["ticks"] = self.timing.summary()["ticks"]
loop_module.ControlLoop.run = timed
from cryod.cli import main
arguments = ["--simulate", "--speed", "max", "--json", "--duration", DURATION, "--data-dir", FOLDER + "/data",
             "--socket", FOLDER + "/c.sock"] + (["--no-feedforward"] if MODE == "ff-off" else []) + CONFIG
# into a real file: the daemon hands stderr's file descriptor to the fault handler
with open(os.devnull, "w") as quiet, contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
    main(arguments)
print(json.dumps(measured))
"""


def without_section(text: str, heading: str) -> str:
    """The YAML ``text`` without the block that starts at the line ``heading`` (and its more indented lines)."""
    lines = text.splitlines(keepends=True)
    start = next(index for index, line in enumerate(lines) if line.startswith(heading))
    indent = len(heading) - len(heading.lstrip())
    end = start + 1
    while end < len(lines) and (not lines[end].strip() or len(lines[end]) - len(lines[end].lstrip()) > indent):
        end += 1
    return "".join(lines[:start] + lines[end:])


def measure(tree: Path, mode: str, duration_s: float, normal_autozero: bool = False,
            arguments: tuple[str, ...] = ()) -> float:
    """Loop-thread CPU per tick (s) of one run (``arguments``: more of cryod's, e.g. the setpoint)."""
    with tempfile.TemporaryDirectory() as folder:
        config = []
        if normal_autozero or mode == "pi":
            text = (REPOSITORY / "config" / "cryod.yaml").read_text().replace(
                "calibration: calibration/", f"calibration: {REPOSITORY}/config/calibration/")
            if normal_autozero:        # the DMMs' NORMal autozero (every third reading), for a baseline that uses it
                text = text.replace("autozero_type: synchronous", "autozero_type: normal")
            if mode == "pi":           # without the term, its section would be an unknown key
                text = without_section(text, "  feedforward:")
            Path(folder, "cryod.yaml").write_text(text)
            config = ["--config", str(Path(folder, "cryod.yaml"))]
        code = (PROBE.replace("TREE", repr(str(tree))).replace("MODE", repr(mode))
                .replace("DURATION", repr(str(duration_s))).replace("FOLDER", repr(folder))
                .replace("CONFIG", repr(config + list(arguments))))
        output = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tree, check=True)
        result = json.loads(output.stdout.strip().splitlines()[-1])
    return result["cpu_s"] / result["ticks"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tree", type=Path, default=None, help="another checkout to compare (mode 'other')")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--duration", type=float, default=1800.0, help="simulated seconds per run")
    parser.add_argument("--normal-autozero", action="store_true",
                        help="this checkout with NORMal autozero (as configured before synchronous was the default)")
    args = parser.parse_args()
    modes = [("pi", REPOSITORY), ("ff-off", REPOSITORY), ("ff", REPOSITORY)]
    if args.tree is not None:
        modes.append(("other", args.tree.resolve()))
    results: dict[str, list[float]] = {mode: [] for mode, _ in modes}
    for _ in range(args.repeat):
        for mode, tree in modes:
            results[mode].append(measure(tree, mode, args.duration, args.normal_autozero and mode != "other"))
    reference = min(results["pi"])
    print(f"loop thread CPU per tick, {args.duration:g} simulated s per run, best of {args.repeat}:")
    print("| mode | best (µs) | all runs (µs) | best / best pi |")
    print("|---|---|---|---|")
    for mode, values in results.items():
        print(f"| {mode} | {1e6 * min(values):.1f} | {', '.join(f'{1e6 * v:.1f}' for v in values)} | "
              f"{min(values) / reference:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
