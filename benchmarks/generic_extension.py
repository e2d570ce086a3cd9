"""What the generic extension removes of effects the catalogue has no physical cause for.

Run: PYTHONPATH=. python3 benchmarks/generic_extension.py [--seeds N] [--json PATH]

Four kinds of effect real cryostats show, each on a cryostat whose base
parameters are off the shipped model's by up to 5 % (another day's operating
point and line), with random noise:

* a breathing stroke: the cooler's line in T5 and T2 scaled +-15 % over
  10 minutes (30 min of PI regulation);
* a wandering cold end: T5's base temperature drifting (1.5 mK rms, 10 min
  correlation), reaching T2 through the flange (coupling 0.6; one hour of
  the identification protocol);
* a 0.37 Hz pickup of 20 µK on the flange thermometer (30 min of PI);
* a heater path the model lacks: a 20 s mode of 0.4 K/W in parallel with G1
  (a stage hanging off the flange; one hour of identification).

The first two are catalogue causes now (``ptc_amplitude_modulation``,
``ptc_stage_drift``): each is analysed twice, with the whole catalogue and with
the catalogue less its cause, which is what a cryostat whose effect no cause
describes looks like; the other two are outside the catalogue. Printed per
record: the verdict, whether a discrepancy is left, the generic families the
extension uses, the fraction of what is left it removes and its held-out gain
(held-out rms over the noise, the model before it against the model with it),
and the gain of the whole extended model over the base model as given.

Results: ``benchmarks/results/analysis_causes.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

from cryod.cli import use_one_blas_thread

use_one_blas_thread()

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent

#: (kind, protocol, duration (s), the catalogue cause that describes it or None, how it is made)
KINDS = (
    ("breathing stroke", "pi_only", 1800.0, "ptc_amplitude_modulation"),
    ("wandering cold end", "identification", 3600.0, "ptc_stage_drift"),
    ("thermometer pickup", "pi_only", 1800.0, None),
    ("heater path the model lacks", "identification", 3600.0, None),
)


def made(kind: str, model, seed: int):
    """(model, make_record keyword arguments) of a cryostat showing ``kind``."""
    from cryod.model import CoolerAmplitudeModulation, PtcStageDrift, TransferFunction

    generator = np.random.default_rng(seed)
    if kind == "breathing stroke":
        return model.with_effects(ptc_amplitude_modulation=CoolerAmplitudeModulation(
            0.15, 600.0, float(generator.uniform(-3.0, 3.0)))), {}
    if kind == "wandering cold end":
        return model.with_effects(ptc_stage_drift=PtcStageDrift(1.5e-3, 600.0, 0.6, 150.0,
                                                                int(generator.integers(0, 1000)))), {}
    if kind == "thermometer pickup":
        phase = float(generator.uniform(0.0, 2.0 * math.pi))
        return model, {"flange_offset_K": lambda t: 20e-6 * np.sin(2.0 * math.pi * 0.37 * t + phase)}
    return dataclasses.replace(model, heater_to_flange=model.heater_to_flange
                               + TransferFunction.first_order_lag(20.0, 0.4)), {}


def analysed(data, shipped, causes) -> dict:
    from cryod.analysis.pipeline import analyze

    started = time.process_time()
    analysis = analyze(data, shipped, causes)
    generic = analysis.generic
    return {"verdict": analysis.cause, "named": analysis.cause_names if analysis.cause not in
            ("none", "unexplained") else [],
            "left": bool(analysis.remaining is not None and analysis.remaining.present),
            "families": list(generic.used) if generic is not None and generic.added else [],
            "removes": generic.score.explained_fraction if generic is not None else None,
            "generic_gain": generic.score.gain.ratio if generic is not None else None,
            "generic_from_to": (generic.score.gain.base, generic.score.gain.extended) if generic is not None
            else None,
            "gain": analysis.decision.gain.ratio, "cpu_s": time.process_time() - started}


def main() -> None:
    from cryod.analysis.candidates import CANDIDATE_CAUSES
    from cryod.analysis.record_data import RecordData
    from cryod.model import load_model
    from cryod.records.record import Record
    from simulated_hw.hidden_effects import other_day, perturbed_base
    from simulated_hw.measurement_programs import make_record

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1, help="records of each kind (default 1)")
    parser.add_argument("--json", default=None, help="also write the results to this JSON file")
    parser.add_argument("--kinds", default=None, help="only these kinds (comma-separated, as in the table)")
    args = parser.parse_args()
    shipped = load_model(ROOT / "config" / "model.yaml")
    results = []
    print("| effect | protocol | catalogue | verdict | discrepancy left | generic families | removes of what is left "
          "| generic held-out gain (rms/noise before -> after) | whole gain |")
    print("|---|---|---|---|---|---|---|---|---|")
    wanted = set(args.kinds.split(",")) if args.kinds else None
    for kind, protocol, duration, cause in KINDS:
        if wanted is not None and kind not in wanted:
            continue
        for seed in range(1, args.seeds + 1):
            model, _ = perturbed_base(other_day(shipped, seed), 100 + seed)     # the base's own parameters first
            model, extra = made(kind, model, seed)
            record = make_record(model, protocol, duration_s=duration, seed=seed, controller_model=shipped, **extra)
            data = RecordData.from_record(Record(record.metadata, record.columns, source=kind))
            catalogues = [("whole", CANDIDATE_CAUSES)]
            if cause is not None:
                catalogues.append((f"without {cause}", tuple(c for c in CANDIDATE_CAUSES if c != cause)))
            for label, causes in catalogues:
                found = {"kind": kind, "protocol": protocol, "seed": seed, "catalogue": label,
                         **analysed(data, shipped, causes)}
                results.append(found)
                removes = "-" if found["removes"] is None else f"{100.0 * found['removes']:.1f} %"
                generic = "-" if found["generic_gain"] is None else (
                    f"{found['generic_gain']:.3g} ({found['generic_from_to'][0]:.3g} -> "
                    f"{found['generic_from_to'][1]:.3g})")
                print(f"| {kind} | {protocol} | {label} | {', '.join(found['named']) or found['verdict']} | "
                      f"{'yes' if found['left'] else 'no'} | {' + '.join(found['families']) or '-'} | {removes} | "
                      f"{generic} | {found['gain']:.3g} |", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str) + "\n", encoding="utf-8")
    print(f"\n{len(results)} analyses, CPU {sum(r['cpu_s'] for r in results):.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
