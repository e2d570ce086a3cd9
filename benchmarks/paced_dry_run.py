"""A dry run faster than real time on a busy machine, against the same run on virtual time.

Run: PYTHONPATH=. python3 benchmarks/paced_dry_run.py [--speed 20] [--duration 600] [--repeat 3] [--load 2]
     [--fixed-multiple]

Each run is a separate ``cryod simulate --duration D --json`` process with the example
configuration and the same noise seed: ``--speed max`` once (virtual time, in process), then
``--speed S`` (paced to S times real time, drivers to the simulated instruments over TCP)
``--repeat`` times. ``--load N`` keeps N extra processes spinning on the CPU while the paced runs
go (a 2-core machine that other people's test suites keep busy). Printed: the machine's load
average, each run's overruns, achieved speed, wall time, the cooler line on T2 over the last 300 s
(``ptc_periodic_amplitude_K``, all harmonics) and its ratio to ``--speed max``'s.
``--fixed-multiple`` runs the paced runs instead on a clock at a fixed multiple of real time
(:class:`drivers.clock.ScaledClock`, which keeps deadlines and counts overruns as real
time does), the baseline the paced clock is measured against.

Results: ``benchmarks/results/paced_dry_run.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parents[1]


def spin() -> None:
    while True:
        pass


#: ``cryod simulate`` with the dry run's clock at a fixed multiple of real time for speeds above 1.
FIXED_MULTIPLE = ("import sys; from cryod.service import simulation; from drivers.clock import ScaledClock; "
                  "simulation.clock_for_speed = lambda speed: ScaledClock(speed); from cryod.cli import main; "
                  "sys.exit(main(sys.argv[1:]))")


def dry_run(speed: str, duration_s: float, folder: Path, name: str, fixed_multiple: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=str(REPOSITORY))
    command = [sys.executable, "-c", FIXED_MULTIPLE] if fixed_multiple else [sys.executable, "-m", "cryod.cli"]
    done = subprocess.run([*command, "simulate", "--speed", speed, "--duration", str(duration_s), "--json",
                           "--seed", "0", "--data-dir", str(folder / name), "--socket", str(folder / f"{name}.sock")],
                          env=env, cwd=folder, capture_output=True, text=True)
    return json.loads(done.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speed", default="20")
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--load", type=int, default=0, help="extra processes spinning during the paced runs")
    parser.add_argument("--fixed-multiple", action="store_true",
                        help="the runs at --speed on a clock at a fixed multiple of real time instead")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        reference = dry_run("max", args.duration, folder, "max")
        line_max = reference["ptc_periodic_amplitude_K"]
        print(f"--speed max: {line_max * 1e6:.1f} µK cooler line, wall {reference['wall_s']:.1f} s, "
              f"achieved speed {reference['achieved_speed']:.0f}")
        spinners = [multiprocessing.Process(target=spin, daemon=True) for _ in range(args.load)]
        for spinner in spinners:
            spinner.start()
        try:
            for run in range(args.repeat):
                load = os.getloadavg()[0]
                summary = dry_run(args.speed, args.duration, folder, f"paced{run}", args.fixed_multiple)
                line = summary["ptc_periodic_amplitude_K"]
                said = (f"{line * 1e6:.1f} µK cooler line ({line / line_max:.4f} of --speed max's)" if line
                        else "no cooler line")
                print(f"--speed {args.speed} run {run + 1}: load average {load:.1f} before it, overruns "
                      f"{summary['overruns']} in {summary['ticks']} ticks, achieved speed "
                      f"{summary['achieved_speed']:.2f}, wall {summary['wall_s']:.1f} s, {said}, exit "
                      f"{summary['exit_code']}")
        finally:
            for spinner in spinners:
                spinner.terminate()


if __name__ == "__main__":
    main()
