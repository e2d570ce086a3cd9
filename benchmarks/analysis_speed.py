"""Wall and CPU time of ``cryod analyze`` on one-hour records at 12.5 Hz (45,000 rows), all candidates.

Run: PYTHONPATH=. python3 benchmarks/analysis_speed.py [--repeat N] [--no-figures] [--tree OTHER_CHECKOUT]
     [--only NAME,NAME...]

For each hidden cause (and a clean record, a base model 15 % off and an
effect outside the catalogue) an identification-style record of one hour is
simulated on a cryostat whose base parameters are off the shipped model's by
up to 5 % (:func:`simulated_hw.hidden_effects.perturbed_base`) and written to a
temporary directory; ``cryod analyze`` is then timed on it as a user runs it
(reading the file, recalibration, every candidate, naming the causes,
discrepancies, figures, report, model file), each run a fresh process
(``python -m cryod.cli``), best of N. Printed: one row per record with the
verdict, the wall and the CPU time of the process (the machine is shared: CPU
time is what the analysis itself costs) and the step times of its report. With
``--tree``, the same records are analysed by another checkout's code in the
same run, alternately, and the ratio of CPU times is printed, with the two
trees' ``--json`` outputs compared (verdicts, causes, every number: equal, or
the largest relative difference).

Results: ``benchmarks/results/analysis_speed.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cryod.model import (
    CoolerAmplitudeModulation, CoolerFrequencyDrift, CoolerHarmonic, DeadTime, HeatCapacityTemperature,
    HeaterNonlinearity, LinkDynamics, PtcStageDrift, SensorLag, TransferFunction, load_model,
)
from cryod.records.record import write_record
from simulated_hw.hidden_effects import perturbed_base
from simulated_hw.measurement_programs import make_record

ROOT = Path(__file__).resolve().parent.parent


def cases(model):
    found = {name: perturbed_base(hidden, seed=index)[0] for index, (name, hidden) in enumerate(_hidden(model).items())}
    far = found["none"]
    found["base model off (heater 15 %)"] = dataclasses.replace(far, heater_to_flange=far.heater_to_flange * 1.15,
                                                                heater_to_ptc_stage=far.heater_to_ptc_stage * 1.15)
    found["outside (extra flange mode)"] = dataclasses.replace(
        far, heater_to_flange=far.heater_to_flange + TransferFunction.first_order_lag(20.0, 0.4))
    return found


def _hidden(model):
    return {
        "none": model,
        "sensor_lag": model.with_effects(sensor_lag=SensorLag(0.3)),
        "link_dynamics": model.with_effects(link_dynamics=LinkDynamics(0.15, 0.8)),
        "dead_time": model.with_effects(dead_time=DeadTime(1.5)),
        "heat_capacity_temperature": model.with_effects(heat_capacity_temperature=HeatCapacityTemperature(1.0, 4.23)),
        "heater_nonlinearity": model.with_effects(heater_nonlinearity=HeaterNonlinearity(0.8)),
        "ptc_harmonics": model.with_ptc(harmonics=(CoolerHarmonic(2, 0.01, 0.4),)),
        "ptc_frequency_drift": model.with_effects(ptc_frequency_drift=CoolerFrequencyDrift(-0.03)),
        "ptc_amplitude_modulation": model.with_effects(ptc_amplitude_modulation=CoolerAmplitudeModulation(0.1, 600.0)),
        "ptc_stage_drift": model.with_effects(ptc_stage_drift=PtcStageDrift(1.5e-3, 600.0, 0.6, 150.0, 4)),
    }


def analysed_in_child(tree: Path, record: Path, out: Path, figures: bool) -> dict:
    """``cryod analyze`` in a fresh process on ``tree``'s code: verdict, wall and CPU time, step times.

    The child runs in ``tree`` (``python -m`` puts the working directory first on the path)."""
    arguments = [sys.executable, "-m", "cryod.cli", "analyze", str(record), "--out", str(out), "--json"]
    arguments += [] if figures else ["--no-figures"]
    environment = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg", OMP_NUM_THREADS="1",
                       OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    started = time.perf_counter()
    child = subprocess.Popen(arguments, env=environment, cwd=tree, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stdout, stderr = child.communicate()
    wall = time.perf_counter() - started
    if child.returncode != 0:
        raise SystemExit(f"cryod analyze failed on {record} with {tree}: {stderr.decode()[-400:]}")
    result = json.loads(stdout)
    return {"wall_s": wall, "named": "+".join(c["cause"] for c in result["causes"]) or result["cause"],
            "cause": result["cause"], "timings": _timings(out / "report.md"), "json": result}


def json_differences(first, second, where: str = "") -> tuple[float, list[str]]:
    """Largest relative difference of the numbers in two ``--json`` outputs, and where anything else differs
    (a verdict, a cause, a list's length; paths of written files aside)."""
    if isinstance(first, dict) and isinstance(second, dict):
        largest, found = 0.0, [f"{where}/{key}" for key in set(first) ^ set(second)]
        for key in set(first) & set(second):
            value, other = json_differences(first[key], second[key], f"{where}/{key}")
            largest, found = max(largest, value), found + other
        return largest, found
    if isinstance(first, list) and isinstance(second, list):
        if len(first) != len(second):
            return 0.0, [f"{where} (length)"]
        largest, found = 0.0, []
        for index, (value, other) in enumerate(zip(first, second)):
            value, other = json_differences(value, other, f"{where}[{index}]")
            largest, found = max(largest, value), found + other
        return largest, found
    numbers = (int, float)
    if isinstance(first, numbers) and isinstance(second, numbers) and not isinstance(first, bool):
        if first == second or (first != first and second != second):        # equal, or both NaN
            return 0.0, []
        return abs(first - second) / max(abs(first), abs(second)), []
    if isinstance(first, str) and isinstance(second, str) and os.sep in first and os.sep in second:
        return 0.0, []
    return 0.0, ([] if first == second else [where])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--no-figures", action="store_true")
    parser.add_argument("--tree", type=Path, default=None, help="another checkout to compare, in the same run")
    parser.add_argument("--only", default=None, metavar="NAMES",
                        help="only these records (comma-separated first words of the hidden column: none, dead_time, "
                             "base, outside, ...)")
    args = parser.parse_args()
    model = load_model(ROOT / "config" / "model.yaml")
    trees = [("this", ROOT)] + ([("other", args.tree.resolve())] if args.tree else [])
    print(f"python {platform.python_version()}, {platform.machine()}, one hour at 12.5 Hz, best of {args.repeat}, "
          f"{'without' if args.no_figures else 'with'} figures")
    print("| hidden | tree | verdict | wall (s) | CPU (s) | of which: recalibration (s) | candidates (s) | "
          "naming (s) | widened model (s) | figures (s) |"
          + (" CPU this / other | JSON against the other |" if args.tree else ""))
    print("|---|---|---|---|---|---|---|---|---|---|" + ("---|---|" if args.tree else ""))
    with tempfile.TemporaryDirectory() as directory:
        wanted = set(args.only.split(",")) if args.only else None
        for name, hidden in cases(model).items():
            if wanted is not None and name.split(" ")[0] not in wanted:
                continue
            path = Path(directory) / f"{name.split(' ')[0]}.csv"
            record = make_record(hidden, "identification", duration_s=3600.0, seed=1)
            write_record(path, record.columns, record.metadata)
            best = {}
            for attempt in range(args.repeat):
                for label, tree in trees:
                    before = os.times()
                    found = analysed_in_child(tree, path, Path(directory) / f"{label}-{attempt}-{path.stem}",
                                              not args.no_figures)
                    after = os.times()
                    found["cpu_s"] = (after.children_user - before.children_user
                                      + after.children_system - before.children_system)
                    if label not in best or found["cpu_s"] < best[label]["cpu_s"]:
                        best[label] = found
            for label, _ in trees:
                found, timings = best[label], best[label]["timings"]
                steps = ("discrepancies", "figures", "total", "base replay and noise", "recalibration",
                         "naming the causes", "wider recalibration", "residual and generic extension")
                candidates = sum(v for k, v in timings.items()
                                 if k not in steps and "next cause" not in k and "widened" not in k)
                widened = sum(v for k, v in timings.items() if "widened" in k or k == "wider recalibration")
                ratio = (f" {best['this']['cpu_s'] / best['other']['cpu_s']:.2f} | {_compared(best)} |"
                         if args.tree and label == "this" else (" | |" if args.tree else ""))
                print(f"| {name} | {label} | {found['named']} | {found['wall_s']:.2f} | {found['cpu_s']:.2f} | "
                      f"{timings.get('recalibration', 0):.2f} | {candidates:.2f} | "
                      f"{timings.get('naming the causes', 0):.2f} | {widened:.2f} | "
                      f"{timings.get('figures', 0):.2f} |{ratio}", flush=True)


def _compared(best: dict) -> str:
    """The two trees' ``--json`` outputs compared: equal, or the largest relative difference of a number and what
    else differs."""
    largest, other = json_differences(best["this"]["json"], best["other"]["json"])
    if not other:
        return "equal" if largest == 0.0 else f"numbers within {largest:.1e} (relative)"
    return f"differs at {', '.join(sorted(other)[:3])}" + (f"; numbers within {largest:.1e}" if largest else "")


def _timings(report: Path) -> dict:
    """Step times from the report's timing table."""
    found, inside = {}, False
    for line in report.read_text().splitlines():
        if line.startswith("## Timing"):
            inside = True
        elif inside and line.startswith("| ") and not line.startswith("| step") and not line.startswith("|---"):
            step, seconds = [part.strip() for part in line.strip("|").split("|")]
            found[step] = float(seconds)
    return found


if __name__ == "__main__":
    main()
