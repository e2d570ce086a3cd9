"""How often ``cryod analyze`` names the right causes on records like real ones: the issue-12 benchmark.

Run: PYTHONPATH=. python3 benchmarks/analysis_causes.py [--records N] [--processes 2] [--seed S] [--json PATH]

Every record comes from a cryostat whose base parameters are off the shipped
model's at random (each gain and time constant by up to +-5 %, the line's phase
on T2 by up to +-0.05 rad: :func:`simulated_hw.hidden_effects.perturbed_base`),
on another day (its own PTC phase, and for odd days its own operating point and
line), with random noise, in one of three protocols
(:mod:`simulated_hw.measurement_programs`): ``identification`` (one hour),
``pi_only`` (30 min, the paper's Fig. 6) and ``feedforward`` (30 min, PI with the
daemon's adaptive feedforward, whose controller model is the shipped one).
Three kinds of record:

* clean: nothing but the perturbed parameters (the answer is ``none``);
* one effect, its size drawn over the range the analysis is meant to detect
  (:data:`RANGES`);
* two effects from different groups (heater path, link and thermometers,
  cooler), each drawn the same way.

Every record is analysed against the shipped model (``config/model.yaml``), as a
user would; a multiprocessing pool of ``--processes`` (2 at most) shares the
work. Printed: Markdown tables of the goals, per cause and protocol, the
records that failed and why, and the analysis times (wall and CPU; the machine
is shared).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from cryod.cli import use_one_blas_thread

use_one_blas_thread()          # one core per process: the machine has two (spawned workers run this too)

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL_DURATIONS_S = {"identification": 3600.0, "pi_only": 1800.0, "feedforward": 1800.0}
PARAMETER_TOLERANCE = 0.2


def _log_uniform(generator, low, high):
    return float(math.exp(generator.uniform(math.log(low), math.log(high))))


def _either(generator, negative, positive):
    """Uniform over the union of two intervals, each drawn with its length's probability."""
    lengths = np.array([negative[1] - negative[0], positive[1] - positive[0]])
    low, high = negative if generator.random() < lengths[0] / lengths.sum() else positive
    return float(generator.uniform(low, high))


def draw_effect(cause: str, generator):
    """(changes for the model, {fitted parameter: true value}) of one effect of random size in its range."""
    from cryod.model import (
        DeadTime, HeatCapacityTemperature, HeaterNonlinearity, LinkDynamics, PtcFrequencyDrift, PtcHarmonic,
        SensorLag,
    )

    if cause == "sensor_lag":
        tau = _log_uniform(generator, *RANGES[cause]["flange_thermometer_time_constant_s"])
        return {"sensor_lag": SensorLag(tau)}, {"flange_thermometer_time_constant_s": tau}
    if cause == "link_dynamics":
        tau = _log_uniform(generator, *RANGES[cause]["time_constant_s"])
        gain = float(generator.uniform(*RANGES[cause]["gain_factor"]))
        return {"link_dynamics": LinkDynamics(tau, gain)}, {"time_constant_s": tau, "gain_factor": gain}
    if cause == "dead_time":
        delay = _log_uniform(generator, *RANGES[cause]["heater_to_flange_s"])
        return {"dead_time": DeadTime(delay)}, {"heater_to_flange_s": delay}
    if cause == "heat_capacity_temperature":
        exponent = _either(generator, *RANGES[cause]["exponent"])
        return {"heat_capacity_temperature": HeatCapacityTemperature(exponent, 4.23)}, {"exponent": exponent}
    if cause == "heater_nonlinearity":
        k = _either(generator, *RANGES[cause]["quadratic_coefficient_per_W"])
        return {"heater_nonlinearity": HeaterNonlinearity(k)}, {"quadratic_coefficient_per_W": k}
    if cause == "ptc_harmonics":
        order = int(generator.choice([2, 3]))
        amplitude = _log_uniform(generator, *RANGES[cause]["amplitude_K"])
        phase = float(generator.uniform(-math.pi, math.pi))
        return ({"harmonics": (PtcHarmonic(order, amplitude, phase),)},
                {f"order_{order}_amplitude_K": amplitude})
    if cause == "ptc_frequency_drift":
        if generator.random() < 0.5:
            rate = _log_uniform(generator, *RANGES[cause]["rate_rad_s_per_hour"]) * float(generator.choice([-1, 1]))
            return {"ptc_frequency_drift": PtcFrequencyDrift(rate)}, {"rate_rad_s_per_hour": rate}
        amplitude = float(generator.uniform(*RANGES[cause]["wander_fraction"])) * 10.83
        period = float(generator.uniform(*RANGES[cause]["wander_period_s"]))
        phase = float(generator.uniform(-math.pi, math.pi))
        return ({"ptc_frequency_drift": PtcFrequencyDrift(0.0, amplitude, period, phase)},
                {"wander_amplitude_rad_s": amplitude, "wander_period_s": period})
    raise ValueError(cause)


#: The range each effect's size is drawn from: the range the analysis is meant to detect, from the smallest
#: that is told apart from a recalibration (the line's phase moved by well over its 0.1 rad tolerance; a time
#: constant's change well over 10 %) to a large one.
RANGES = {
    "sensor_lag": {"flange_thermometer_time_constant_s": (0.03, 1.0)},
    "link_dynamics": {"time_constant_s": (0.03, 0.3), "gain_factor": (0.7, 1.3)},
    "dead_time": {"heater_to_flange_s": (0.3, 8.0)},
    "heat_capacity_temperature": {"exponent": ((-3.0, -0.5), (0.5, 3.0))},
    "heater_nonlinearity": {"quadratic_coefficient_per_W": ((-0.8, -0.3), (0.3, 3.0))},
    "ptc_harmonics": {"amplitude_K": (0.002, 0.025)},
    "ptc_frequency_drift": {"rate_rad_s_per_hour": (0.003, 0.05), "wander_fraction": (0.002, 0.01),
                            "wander_period_s": (600.0, 1800.0)},
}


def plan(records: int, seed: int) -> list[dict]:
    """The records of the benchmark: kind, causes, protocol, seeds (about 1/5 clean, 1/2 one effect, the rest two)."""
    from simulated_hw.hidden_effects import EFFECT_GROUPS

    causes = [cause for group in EFFECT_GROUPS.values() for cause in group]
    groups = list(EFFECT_GROUPS.values())
    pairs = [(first, second) for index, group in enumerate(groups) for later in groups[index + 1:]
             for first in group for second in later]
    protocols = list(PROTOCOL_DURATIONS_S)
    generator = np.random.default_rng(seed)
    clean = max(3, records // 5)
    single = max(len(causes), records // 2)
    double = max(records - clean - single, 0)
    jobs = []
    for index in range(clean):
        jobs.append({"kind": "clean", "causes": [], "protocol": protocols[index % 3]})
    for index in range(single):
        jobs.append({"kind": "one effect", "causes": [causes[index % len(causes)]],
                     "protocol": protocols[(index // len(causes)) % 3]})
    for index in range(double):
        jobs.append({"kind": "two effects", "causes": list(pairs[index % len(pairs)]),
                     "protocol": protocols[(index // len(pairs) + index) % 3]})
    for index, job in enumerate(jobs):
        job["index"] = index
        job["seed"] = int(generator.integers(1, 2 ** 31))
    return jobs


def run_one(job: dict) -> dict:
    """Make one record and analyse it; returns what was found."""
    from cryod.analysis.pipeline import analyze
    from cryod.analysis.record_data import RecordData
    from cryod.model import load_model
    from cryod.records.record import Record
    from simulated_hw.hidden_effects import other_day, perturbed_base
    from simulated_hw.measurement_programs import make_record

    generator = np.random.default_rng(job["seed"])
    shipped = load_model(ROOT / "config" / "model.yaml")
    model = other_day(shipped, int(generator.integers(0, 4)))
    truths = {}
    for cause in job["causes"]:
        changes, truth = draw_effect(cause, generator)
        if "harmonics" in changes:
            model = model.with_ptc(harmonics=changes["harmonics"])
        else:
            model = model.with_effects(**changes)
        truths[cause] = truth
    model, perturbation = perturbed_base(model, int(generator.integers(1, 2 ** 31)))
    protocol = job["protocol"]
    record = make_record(model, protocol, duration_s=PROTOCOL_DURATIONS_S[protocol],
                         seed=int(generator.integers(1, 2 ** 31)), controller_model=shipped)
    data = RecordData.from_record(Record(record.metadata, record.columns, source=f"record {job['index']}"))
    started, cpu = time.perf_counter(), time.process_time()
    try:
        analysis = analyze(data, shipped)
    except Exception as error:                                   # reported as a failure, the run goes on
        return {**job, "truths": truths, "named": [], "cause": f"error: {error}", "reason": repr(error),
                "parameters": {}, "wall_s": time.perf_counter() - started, "cpu_s": time.process_time() - cpu}
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    named = {item.cause: _plain(item.fit.parameters) for item in analysis.causes} \
        if analysis.cause not in ("none", "unexplained") else {}
    return {**job, "truths": truths, "named": list(named), "cause": analysis.cause,
            "reason": analysis.decision.reason, "parameters": named, "wall_s": wall, "cpu_s": cpu,
            "gain": analysis.decision.gain.ratio, "recalibrated": analysis.recalibrated,
            "perturbation": perturbation}


def _plain(parameters: dict) -> dict:
    return {name: (float(value) if isinstance(value, (int, float, np.floating)) else value)
            for name, value in parameters.items()}


def judged(result: dict) -> dict:
    """Right or wrong, and each true parameter's relative error."""
    truths = result["truths"]
    right = sorted(result["named"]) == sorted(truths)
    errors = {}
    for cause, truth in truths.items():
        fitted = result["parameters"].get(cause, {})
        for name, true in truth.items():
            value = fitted.get(name)
            errors[f"{cause}.{name}"] = abs(value - true) / abs(true) if value is not None else math.inf
    within = right and all(error <= PARAMETER_TOLERANCE for error in errors.values())
    return {"right": right, "errors": errors, "parameters_within": within}


def tables(results: list[dict]) -> str:
    """The Markdown tables of the benchmark."""
    lines = []
    by_kind = defaultdict(list)
    for result in results:
        by_kind[result["kind"]].append((result, judged(result)))
    goals = {"clean": ("`none`", 0.97), "one effect": ("cause named right", 0.97),
             "two effects": ("both causes named, nothing else", 0.90)}
    lines += ["| records | count | goal | right | rate | goal met | every parameter within 20 % (of those right) |",
              "|---|---|---|---|---|---|---|"]
    for kind, (goal, rate) in goals.items():
        items = by_kind.get(kind, [])
        right = sum(j["right"] for _, j in items)
        within = sum(j["parameters_within"] for _, j in items)
        share = right / len(items) if items else math.nan
        parameters = f"{within} of {right}" if kind != "clean" else "-"
        lines.append(f"| {kind} | {len(items)} | {goal} >= {100 * rate:.0f} % | {right} | {100 * share:.1f} % | "
                     f"{'yes' if share >= rate else 'no'} | {parameters} |")
    lines += ["", "| cause | protocol | records | named right | parameters within 20 % |", "|---|---|---|---|---|"]
    cells = defaultdict(lambda: [0, 0, 0])
    for result, judgement in by_kind.get("one effect", []):
        cell = cells[(result["causes"][0], result["protocol"])]
        cell[0] += 1
        cell[1] += judgement["right"]
        cell[2] += judgement["parameters_within"]
    for (cause, protocol), (count, right, within) in sorted(cells.items()):
        lines.append(f"| {cause} | {protocol} | {count} | {right} | {within} |")
    lines += ["", "| pair | protocol | named |", "|---|---|---|"]
    for result, judgement in by_kind.get("two effects", []):
        mark = "" if judgement["right"] else " **wrong**"
        lines.append(f"| {' + '.join(result['causes'])} | {result['protocol']} | "
                     f"{', '.join(result['named']) or result['cause']}{mark} |")
    failures = [(result, judgement) for result in results for judgement in [judged(result)]
                if not judgement["right"] or (result["kind"] != "clean" and not judgement["parameters_within"])]
    lines += ["", "Records that failed (cause wrong, or a parameter off by more than 20 %):", "",
              "| record | protocol | true | named | parameters (fitted / true) | why |", "|---|---|---|---|---|---|"]
    for result, judgement in failures:
        parts = []
        for cause, truth in result["truths"].items():
            for name, true in truth.items():
                fitted = result["parameters"].get(cause, {}).get(name)
                parts.append(f"{name} {fitted:.4g} / {true:.4g}" if fitted is not None else f"{name} - / {true:.4g}")
        lines.append(f"| {result['index']} | {result['protocol']} | {' + '.join(result['causes']) or 'none'} | "
                     f"{', '.join(result['named']) or result['cause']} | {'; '.join(parts) or '-'} | "
                     f"{result['reason'][:300]} |")
    lines += ["", "| records | protocol | count | analysis wall time median / max (s) | CPU time median / max (s) |",
              "|---|---|---|---|---|"]
    groups = defaultdict(list)
    for result in results:
        groups[(result["kind"], result["protocol"])].append(result)
    for (kind, protocol), items in sorted(groups.items()):
        wall = np.array([item["wall_s"] for item in items])
        cpu = np.array([item["cpu_s"] for item in items])
        lines.append(f"| {kind} | {protocol} | {len(items)} | {np.median(wall):.1f} / {wall.max():.1f} | "
                     f"{np.median(cpu):.1f} / {cpu.max():.1f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=110, help="records in all (default 110)")
    parser.add_argument("--processes", type=int, default=2, help="worker processes, at most 2 (default 2)")
    parser.add_argument("--seed", type=int, default=12, help="seed of the plan (default 12)")
    parser.add_argument("--json", default=None, help="also write every result to this JSON file")
    args = parser.parse_args()
    jobs = plan(args.records, args.seed)
    processes = max(1, min(args.processes, 2))
    results = []
    started = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(processes) as pool:
        for result in pool.imap_unordered(run_one, jobs):
            results.append(result)
            print(f"{len(results)}/{len(jobs)} record {result['index']} ({result['kind']}, {result['protocol']}): "
                  f"{' + '.join(result['causes']) or 'none'} -> {', '.join(result['named']) or result['cause']} "
                  f"({result['wall_s']:.1f} s)", file=sys.stderr, flush=True)
    results.sort(key=lambda result: result["index"])
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str) + "\n", encoding="utf-8")
    print(f"{len(results)} records, {processes} processes, {time.perf_counter() - started:.0f} s\n")
    print(tables(results))


if __name__ == "__main__":
    main()
