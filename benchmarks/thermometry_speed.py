"""Time of one scalar conversion for each calibration format.

The simulated multimeter turns the simulated temperature into a resistance on
every reading, and the daemon turns every resistance back into a temperature
inside its 80 ms cycle, so a scalar call must stay well under 50 µs.

Usage::

    python3 benchmarks/thermometry_speed.py [CALIBRATION_FILE ...]

With no argument it times the tables in ``tests/data/calibration``. It prints
the best of five runs of each call, in µs per call (the best run is the one
least disturbed by the rest of the machine). The result on the project's
reference machine is in ``benchmarks/results/thermometry_speed.md``.
"""

from __future__ import annotations

import sys
import time
import timeit
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))

from cryod.thermometry import CalibrationCurve, load_calibration  # noqa: E402

DEFAULT_FILES = ["X186279.340", "X162690.cof", "X162690.dat", "X100332.dat", "X98650.txt"]


def scalar_call_times_us(curve: CalibrationCurve, calls: int = 20000, repeats: int = 5,
                         timer=time.perf_counter) -> dict[str, float]:
    """Best-of-``repeats`` time in µs of one scalar call of each conversion, at 4.2 K (``timer``: the
    clock, wall time by default; ``time.thread_time`` counts only this thread's CPU)."""
    temperature_K = 4.2
    resistance_ohm = curve.resistance_ohm(temperature_K)
    conversions = {
        "temperature_K(R)": lambda: curve.temperature_K(resistance_ohm),
        "resistance_ohm(T)": lambda: curve.resistance_ohm(temperature_K),
        "sensitivity_ohm_per_K(T)": lambda: curve.sensitivity_ohm_per_K(temperature_K),
    }
    return {name: min(timeit.repeat(call, number=calls, repeat=repeats, timer=timer)) / calls * 1e6
            for name, call in conversions.items()}


def main(arguments: list[str]) -> int:
    paths = [Path(argument) for argument in arguments] or \
        [REPOSITORY / "tests" / "data" / "calibration" / name for name in DEFAULT_FILES]
    print(f"{'file':16s} {'curve':18s} {'T(R) µs':>8s} {'R(T) µs':>8s} {'dR/dT µs':>9s}")
    for path in paths:
        curve = load_calibration(path)
        times = scalar_call_times_us(curve)
        print(f"{path.name:16s} {type(curve).__name__:18s} {times['temperature_K(R)']:8.2f} "
              f"{times['resistance_ohm(T)']:8.2f} {times['sensitivity_ohm_per_K(T)']:9.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
