"""One simulated hour (45,000 steps of 80 ms) of the plant, against scipy.signal.lsim.

Run: python3 benchmarks/plant_speed.py [--repeat N]

All variants get the same open-loop input: a heater program that changes every
10 s (0 to 150 mW) and the PTC line. Reported: best wall time of N repeats of
each, the ratio to lsim measured in this same run, and how far lsim's result
is from the exact one (lsim holds the PTC heat constant over each 80 ms step,
which distorts and aliases the 1.72 Hz line; the plant evaluates it exactly).

Results: ``benchmarks/results/plant_speed.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
from scipy import linalg, signal

from cryod.model import CryostatPlant, load_model, simulate
from cryod.model.cooler_path import CoolerDrive

PERIOD_S = 0.08
STEPS = 45_000


def heater_program(times: np.ndarray) -> np.ndarray:
    levels = np.random.default_rng(0).uniform(0.0, 0.15, int(times[-1] // 10.0) + 1)
    return levels[(times // 10.0).astype(int)]


def run_stepping(model, times, powers):
    plant = CryostatPlant(model, 0.0, 0.0)
    flange = np.empty(times.size)
    for k, (instant, power) in enumerate(zip(times.tolist(), powers.tolist())):
        plant.advance_to(instant)
        flange[k] = plant.temperatures()[0]
        plant.set_heater_power(power, instant)
    return flange


def lsim_system(model):
    """Block-diagonal state space: inputs (P, q), output T2 deviation."""
    blocks = [signal.tf2ss(tf.numerator, tf.denominator)
              for tf in (model.heater_to_thermometer, model.ptc_heat_to_thermometer)]
    a = linalg.block_diag(*(b[0] for b in blocks))
    b = linalg.block_diag(*(b[1] for b in blocks))
    c = np.hstack([b_[2] for b_ in blocks])
    d = np.hstack([b_[3] for b_ in blocks])
    return signal.StateSpace(a, b, c, d)


def run_lsim(system, model, times, powers):
    drive = CoolerDrive(model)
    phase, frequency = drive.cycle.phase_and_frequency(times)
    heat = sum(np.real(c.heat_phasor * frequency * np.exp(1j * (c.order * phase + c.phase_rad)))
               for c in drive.components)
    inputs = np.column_stack([powers, heat])
    _, output, _ = signal.lsim(system, inputs, times, interp=False)
    return model.operating_point.flange_temperature_K + output


def best_of(repeat, function):
    times = []
    result = None
    for _ in range(repeat):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    model = load_model()
    times = np.arange(STEPS) * PERIOD_S
    powers = heater_program(times)
    system = lsim_system(model)
    exact = simulate(model, times, powers, initial_heater_power_w=0.0).flange_K
    rows = []
    t_lsim, lsim_out = best_of(args.repeat, lambda: run_lsim(system, model, times, powers))
    t_step, step_out = best_of(args.repeat, lambda: run_stepping(model, times, powers))
    t_batch, batch_out = best_of(args.repeat, lambda: simulate(model, times, powers, initial_heater_power_w=0.0))
    rows.append(("scipy.signal.lsim (ZOH)", t_lsim, np.max(np.abs(lsim_out - exact))))
    rows.append(("CryostatPlant, step by step", t_step, np.max(np.abs(step_out - exact))))
    rows.append(("simulate(), whole record", t_batch, np.max(np.abs(batch_out.flange_K - exact))))
    print(f"python {platform.python_version()}, numpy {np.__version__}, {STEPS} steps of {PERIOD_S} s, "
          f"best of {args.repeat}")
    print("| variant | wall time (s) | vs lsim | max deviation of T2 from exact (K) |")
    print("|---|---|---|---|")
    for name, seconds, deviation in rows:
        print(f"| {name} | {seconds:.3f} | {t_lsim / seconds:.1f}x faster | {deviation:.2e} |")


if __name__ == "__main__":
    main()
