"""Wall time of ``cryod analyze`` on one-hour records at 12.5 Hz (45,000 rows), all candidates.

Run: PYTHONPATH=. python3 benchmarks/analysis_speed.py [--repeat N] [--no-figures]

For each hidden cause (and a clean record) an identification-style record of
one hour is simulated on a cryostat whose base parameters are off the shipped
model's by up to 5 % (:func:`simulated_hw.hidden_effects.perturbed_base`) and
written to a temporary directory; ``cryod analyze`` is then timed on it as a
user runs it (reading the file, recalibration, every candidate, naming the
causes, discrepancies, figures, report, model file), best of N. Printed: one
row per record with the named cause, the wall time of each step and the
process's CPU time (the machine is shared: CPU time is what the analysis
itself costs).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import platform
import tempfile
import time
from pathlib import Path

from cryod import cli
from cryod.model import (
    DeadTime, HeatCapacityTemperature, HeaterNonlinearity, LinkDynamics, PtcFrequencyDrift, PtcHarmonic, SensorLag,
    load_model,
)
from cryod.records.record import write_record
from simulated_hw.hidden_effects import perturbed_base
from simulated_hw.measurement_programs import make_record

ROOT = Path(__file__).resolve().parent.parent


def cases(model):
    return {name: perturbed_base(hidden, seed=index)[0] for index, (name, hidden) in enumerate(_hidden(model).items())}


def _hidden(model):
    return {
        "none": model,
        "sensor_lag": model.with_effects(sensor_lag=SensorLag(0.3)),
        "link_dynamics": model.with_effects(link_dynamics=LinkDynamics(0.15, 0.8)),
        "dead_time": model.with_effects(dead_time=DeadTime(1.5)),
        "heat_capacity_temperature": model.with_effects(heat_capacity_temperature=HeatCapacityTemperature(1.0, 4.23)),
        "heater_nonlinearity": model.with_effects(heater_nonlinearity=HeaterNonlinearity(0.8)),
        "ptc_harmonics": model.with_ptc(harmonics=(PtcHarmonic(2, 0.01, 0.4),)),
        "ptc_frequency_drift": model.with_effects(ptc_frequency_drift=PtcFrequencyDrift(-0.03)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--no-figures", action="store_true")
    args = parser.parse_args()
    model = load_model(ROOT / "config" / "model.yaml")
    print(f"python {platform.python_version()}, {platform.machine()}, one hour at 12.5 Hz, best of {args.repeat}")
    print("| hidden | named | total (s) | CPU (s) | of which: recalibration (s) | candidates (s) | naming (s) | "
          "discrepancies (s) | figures (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as directory:
        for name, hidden in cases(model).items():
            path = Path(directory) / f"{name}.csv"
            record = make_record(hidden, "identification", duration_s=3600.0, seed=1)
            write_record(path, record.columns, record.metadata)
            best = None
            for attempt in range(args.repeat):
                out = Path(directory) / f"{name}-{attempt}"
                started, cpu = time.perf_counter(), time.process_time()
                argv = ["analyze", str(path), "--out", str(out), "--json"] + (["--no-figures"] if args.no_figures else [])
                buffer = io.StringIO()
                with contextlib.redirect_stdout(buffer):
                    status = cli.main(argv)
                elapsed, cpu = time.perf_counter() - started, time.process_time() - cpu
                if status != 0:
                    raise SystemExit(f"cryod analyze failed on {path}")
                result = json.loads(buffer.getvalue())
                timings = _timings(out / "report.md")
                if best is None or elapsed < best[0]:
                    best = (elapsed, cpu, "+".join(c["cause"] for c in result["causes"]) or result["cause"], timings)
            elapsed, cpu, cause, timings = best
            steps = ("discrepancies", "figures", "total", "base replay and noise", "recalibration",
                     "naming the causes")
            candidates = sum(v for k, v in timings.items() if k not in steps and "next cause" not in k)
            print(f"| {name} | {cause} | {elapsed:.2f} | {cpu:.2f} | {timings.get('recalibration', 0):.2f} | "
                  f"{candidates:.2f} | {timings.get('naming the causes', 0):.2f} | "
                  f"{timings.get('discrepancies', 0):.2f} | {timings.get('figures', 0):.2f} |")


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
