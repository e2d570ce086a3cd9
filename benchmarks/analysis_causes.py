"""What ``cryod analyze`` names on records with hidden effects: cause, fitted vs true parameters, gain, time.

Run: PYTHONPATH=. python3 benchmarks/analysis_causes.py [--magnitude 0|1|2|all]

Records: the identification protocol (one hour) and the PI-only protocol
(30 min) of simulated_hw.measurement_programs, on another day's cryostat
(simulated_hw.hidden_effects.other_day), seed 2; then clean records and the
disturbances outside the cause list. Printed as a Markdown table.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from cryod.analysis.pipeline import analyze
from cryod.analysis.record_data import RecordData
from cryod.model import load_model
from cryod.records.record import Record
from simulated_hw.hidden_effects import DISTURBANCES, MAGNITUDES, hidden_model, other_day, within
from simulated_hw.measurement_programs import make_record

ROOT = Path(__file__).resolve().parent.parent
DURATIONS_S = {"identification": 3600.0, "pi_only": 1800.0}


def run(model, base, protocol: str, seed: int, **disturbance):
    record = make_record(model, protocol, duration_s=DURATIONS_S[protocol], seed=seed, **disturbance)
    data = RecordData.from_record(Record(record.metadata, record.columns, source=protocol))
    started = time.perf_counter()
    analysis = analyze(data, base)
    return analysis, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--magnitude", default="1", help="0, 1, 2 or all")
    args = parser.parse_args()
    magnitudes = [0, 1, 2] if args.magnitude == "all" else [int(args.magnitude)]
    base = load_model(ROOT / "config" / "model.yaml")
    print("| hidden | protocol | named | fitted (true) | gain | analysis (s) |")
    print("|---|---|---|---|---|---|")
    for cause in MAGNITUDES:
        for magnitude in magnitudes:
            for protocol in DURATIONS_S:
                model, truth = hidden_model(base, cause, magnitude, variant=magnitude + 2)
                analysis, seconds = run(model, base, protocol, 2)
                fitted = analysis.fits[cause].parameters
                parts = []
                for name, true in truth.items():
                    mark = "" if within(fitted.get(name), true) else " **off**"
                    parts.append(f"{name} {fitted.get(name, float('nan')):.4g} ({true:.4g}){mark}")
                print(f"| {cause} | {protocol} | {analysis.cause} | {'; '.join(parts)} | "
                      f"{analysis.decision.gain.ratio:.4g} | {seconds:.1f} |")
    for protocol in DURATIONS_S:
        analysis, seconds = run(other_day(base, 3), base, protocol, 4)
        print(f"| (clean) | {protocol} | {analysis.cause} | - | {analysis.decision.gain.ratio:.4g} | {seconds:.1f} |")
    for name, make in DISTURBANCES.items():
        for protocol in DURATIONS_S:
            analysis, seconds = run(other_day(base, 1), base, protocol, 5, **make(DURATIONS_S[protocol]))
            print(f"| {name} (outside the list) | {protocol} | {analysis.cause} | - | "
                  f"{analysis.decision.gain.ratio:.4g} | {seconds:.1f} |")


if __name__ == "__main__":
    main()
