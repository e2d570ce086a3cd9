"""How often ``cryod analyze`` names the right causes on records of an independent simulator, pairs above all.

Run: PYTHONPATH=. python3 benchmarks/analysis_independent.py [--processes 2] [--seed S] [--json PATH]
     [--only INDEXES] [--results PATH]

The records come from :mod:`simulated_hw.lumped_cryostat`: a lumped thermal network integrated in time, which
shares no code with :mod:`cryod.model` and whose effects have forms the catalogue does not use (a thermometer on
a mount, a link of two masses, a transport delay, copper's heat capacity raised to a power, a heater whose power
goes as ``P (1 + c P^2)``). The analysis' own benchmark (``benchmarks/analysis_causes.py``) makes its records with
the model family the analysis fits, so it shares the analysis' blind spots; this one does not.

The plan (seed 35 by default): in each of three protocols (``identification``, an hour; ``pi_only``, 30 min;
``paper``, 40 min: the paper's 8.8 mW step then PI to 5 K), a clean record, each effect alone, and every pair of
a line-path effect (thermometer lag, link) with a heater-path effect (delay, heater, heat capacity): 3 + 15 + 18 =
36 records, each on its own network (heat capacities and conductances off by up to 3 %, the cooler's line
another day's), each effect's size drawn from :data:`RANGES`. Every record is analysed against the shipped model
(``config/model.yaml``), as a user would, with one BLAS thread per process.

A record is right when the causes named are exactly the effects' catalogue causes (:data:`CATALOGUE`; ``none``
for a clean record); ``base_model_off`` is wrong. Printed and written to ``--results`` (default
``benchmarks/results/analysis-independent.md``): the rates per kind and per kind and protocol, every record (truth, causes named, a
parameter the analysis left at a bound, CPU time), the CPU time per record of each kind and protocol and the
slowest three.
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

from benchmarks.analysis_causes import either, log_uniform  # the same draws as the catalogue benchmark's
from cryod.cli import use_one_blas_thread

use_one_blas_thread()

ROOT = Path(__file__).resolve().parent.parent
DURATIONS_S = {"identification": 3600.0, "pi_only": 1800.0, "paper": 2400.0}
#: Each effect's catalogue cause.
CATALOGUE = {"thermometer_lag": "sensor_lag", "link": "link_dynamics", "delay": "dead_time",
             "heater_sag": "heater_nonlinearity", "heat_capacity": "heat_capacity_temperature"}
LINE_PATH = ("thermometer_lag", "link")
HEATER_PATH = ("delay", "heater_sag", "heat_capacity")
#: Ranges the effects' sizes are drawn from (log-uniform for time constants; either sign for the laws).
RANGES = {"thermometer_lag": (0.05, 1.0), "link_time_constant": (0.05, 0.3), "link_gain": (0.7, 1.3),
          "delay": (0.3, 8.0), "heat_capacity": ((-1.4, -0.3), (0.3, 1.4)), "heater_sag": ((-3.0, -1.0), (1.0, 8.0))}
RESULTS = ROOT / "benchmarks" / "results" / "analysis-independent.md"


def draw_effects(names, generator) -> tuple[dict, dict]:
    """(:class:`~simulated_hw.lumped_cryostat.Effects` keyword arguments, {effect: its size in words}) for the
    effects ``names``."""
    fields, truth = {}, {}
    for name in names:
        if name == "thermometer_lag":
            fields["thermometer_lag_s"] = log_uniform(generator, *RANGES["thermometer_lag"])
            truth[name] = f"{fields['thermometer_lag_s']:.3g} s"
        elif name == "link":
            fields["link_time_constant_s"] = log_uniform(generator, *RANGES["link_time_constant"])
            fields["link_gain"] = float(generator.uniform(*RANGES["link_gain"]))
            truth[name] = f"{fields['link_time_constant_s']:.3g} s, g {fields['link_gain']:.3g}"
        elif name == "delay":
            fields["delay_s"] = log_uniform(generator, *RANGES["delay"])
            truth[name] = f"{fields['delay_s']:.3g} s"
        elif name == "heat_capacity":
            fields["heat_capacity_power"] = either(generator, *RANGES["heat_capacity"])
            truth[name] = f"p {fields['heat_capacity_power']:.3g}"
        elif name == "heater_sag":
            fields["heater_sag_per_W2"] = either(generator, *RANGES["heater_sag"])
            truth[name] = f"c {fields['heater_sag_per_W2']:.3g} /W^2"
        else:
            raise ValueError(name)
    return fields, truth


def plan(seed: int) -> list[dict]:
    """The records: per protocol a clean one, each effect alone, every line-path x heater-path pair."""
    generator = np.random.default_rng(seed)
    jobs = []
    for protocol in DURATIONS_S:
        jobs.append({"kind": "clean", "effects": [], "protocol": protocol})
        for name in LINE_PATH + HEATER_PATH:
            jobs.append({"kind": "one effect", "effects": [name], "protocol": protocol})
        for line in LINE_PATH:
            for heater in HEATER_PATH:
                jobs.append({"kind": "two effects", "effects": [line, heater], "protocol": protocol})
    for index, job in enumerate(jobs):
        job["index"] = index
        job["seed"] = int(generator.integers(1, 2 ** 31))
    return jobs


def make_data(job: dict):
    """The record of ``job`` as :class:`~cryod.analysis.record_data.RecordData`, and the effects' sizes."""
    from cryod.analysis.record_data import RecordData
    from cryod.records.record import Record
    from simulated_hw.lumped_cryostat import Effects, LumpedCryostat, run_protocol

    generator = np.random.default_rng(job["seed"])
    fields, truth = draw_effects(job["effects"], generator)
    cryostat = LumpedCryostat.nominal().spread(generator).with_effects(Effects(**fields))
    columns = run_protocol(cryostat, job["protocol"], DURATIONS_S[job["protocol"]], int(generator.integers(1, 2 ** 31)))
    record = Record({"source": "simulated_hw.lumped_cryostat", "protocol": job["protocol"]}, columns,
                    source=f"independent record {job['index']}")
    return RecordData.from_record(record), truth


def run_one(job: dict) -> dict:
    """Make one record and analyse it (an error is reported as a wrong answer, the run goes on)."""
    try:
        return _run_one(job)
    except Exception as error:
        return {**job, "truth": {}, "named": [], "cause": f"error: {error!r}", "cpu_s": 0.0, "wall_s": 0.0,
                "at_bound": [], "parameters": {}}


def _run_one(job: dict) -> dict:
    from cryod.analysis.pipeline import analyze
    from cryod.model import load_model

    data, truth = make_data(job)
    shipped = load_model(ROOT / "config" / "model.yaml")
    started, cpu = time.perf_counter(), time.process_time()
    analysis = analyze(data, shipped)
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    named = [item.cause for item in analysis.causes] if analysis.cause not in ("none", "unexplained") else []
    parameters = {item.cause: {name: value for name, value in item.fit.parameters.items()
                               if isinstance(value, (int, float))} for item in analysis.causes}
    bounds = getattr(analysis, "at_bound", ()) or ()
    return {**job, "truth": truth, "named": named, "cause": analysis.cause, "cpu_s": cpu, "wall_s": wall,
            "at_bound": [item.as_dict() if hasattr(item, "as_dict") else str(item) for item in bounds],
            "parameters": {cause: {name: float(value) for name, value in values.items()}
                           for cause, values in parameters.items()},
            "reason": analysis.decision.reason}


def right(result: dict) -> bool:
    """The causes named are exactly the effects' catalogue causes (``none`` for a clean record)."""
    if result["kind"] == "clean":
        return result["cause"] == "none"
    return result["cause"] != "base_model_off" and sorted(result["named"]) == sorted(
        CATALOGUE[name] for name in result["effects"])


def _parameters_text(result: dict) -> str:
    parts = []
    for cause, values in result.get("parameters", {}).items():
        shown = ", ".join(f"{name.replace('_', ' ')} {value:.3g}" for name, value in values.items()
                          if not name.startswith("reference"))
        parts.append(f"{cause}: {shown}")
    return "; ".join(parts) or "-"


def tables(results: list[dict], command: str) -> str:
    """The Markdown of the results file: goals, every record, CPU per record."""
    lines = ["# `cryod analyze` on records of an independent simulator", "",
             "Made by `benchmarks/analysis_independent.py` (the module doc says what the records are); "
             "the method: docs/explanation/analysis-method.md.", "", "    " + command, ""]
    by_kind = defaultdict(list)
    for result in results:
        by_kind[result["kind"]].append(result)
    lines += ["| records | count | right | rate |", "|---|---|---|---|"]
    for kind in ("clean", "one effect", "two effects"):
        items = by_kind.get(kind, [])
        count = sum(right(item) for item in items)
        lines.append(f"| {kind} | {len(items)} | {count} | {100.0 * count / max(len(items), 1):.1f} % |")
    lines += ["", "By protocol (right of count):", "", "| records | " + " | ".join(DURATIONS_S) + " |",
              "|---|" + "---|" * len(DURATIONS_S)]
    for kind in ("clean", "one effect", "two effects"):
        cells = []
        for protocol in DURATIONS_S:
            items = [item for item in by_kind.get(kind, []) if item["protocol"] == protocol]
            cells.append(f"{sum(right(item) for item in items)} of {len(items)}")
        lines.append(f"| {kind} | " + " | ".join(cells) + " |")
    wrong = sum(bool(set(result["named"]) - {CATALOGUE[name] for name in result["effects"]})
                or result["cause"] == "base_model_off" for result in results)
    lines += ["", f"A catalogue cause not in the record (or `base_model_off`) in {wrong} of {len(results)} records.",
              "", "| record | protocol | truth | verdict | causes named (parameters) | at a bound | right | CPU (s) |",
              "|---|---|---|---|---|---|---|---|"]
    for result in results:
        truth = "; ".join(f"{name} {size}" for name, size in result["truth"].items()) or "clean"
        bound = "; ".join(item.get("text", str(item)) if isinstance(item, dict) else str(item)
                          for item in result.get("at_bound", [])) or "-"
        lines.append(f"| {result['index']} | {result['protocol']} | {truth} | {result['cause']} | "
                     f"{_parameters_text(result)} | {bound} | {'yes' if right(result) else '**no**'} | "
                     f"{result['cpu_s']:.1f} |")
    lines += ["", "CPU time of the analysis per record (the analysis alone, one BLAS thread; the machine shared):",
              "", "| records | protocol | count | CPU median (s) | CPU max (s) |", "|---|---|---|---|---|"]
    groups = defaultdict(list)
    for result in results:
        groups[(result["kind"], result["protocol"])].append(result["cpu_s"])
    for (kind, protocol), values in sorted(groups.items()):
        lines.append(f"| {kind} | {protocol} | {len(values)} | {np.median(values):.1f} | {max(values):.1f} |")
    slowest = sorted(results, key=lambda item: -item["cpu_s"])[:3]
    lines += ["", "The slowest three: " + "; ".join(
        f"record {item['index']} ({item['protocol']}, {' + '.join(item['effects']) or 'clean'}) {item['cpu_s']:.1f} s"
        for item in slowest) + "."]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--processes", type=int, default=2, help="worker processes, at most 2 (default 2)")
    parser.add_argument("--seed", type=int, default=35, help="seed of the plan (default 35)")
    parser.add_argument("--json", default=None, help="also write every result to this JSON file")
    parser.add_argument("--only", default=None, metavar="INDEXES", help="only these records (comma-separated)")
    parser.add_argument("--results", default=str(RESULTS),
                        help="the Markdown results file (default benchmarks/results/analysis-independent.md; "
                             "'-' for none)")
    args = parser.parse_args()
    jobs = plan(args.seed)
    if args.only:
        wanted = {int(index) for index in args.only.split(",")}
        jobs = [job for job in jobs if job["index"] in wanted]
    results = []
    with multiprocessing.get_context("spawn").Pool(max(1, min(args.processes, 2))) as pool:
        for result in pool.imap_unordered(run_one, jobs):
            results.append(result)
            print(f"{len(results)}/{len(jobs)} record {result['index']} ({result['protocol']}): "
                  f"{' + '.join(result['effects']) or 'clean'} -> {', '.join(result['named']) or result['cause']} "
                  f"({result['cpu_s']:.1f} s CPU)", file=sys.stderr, flush=True)
    results.sort(key=lambda item: item["index"])
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str) + "\n", encoding="utf-8")
    command = "PYTHONPATH=. nice -n 10 python3 benchmarks/analysis_independent.py --processes 2" + (
        f" --only {args.only}" if args.only else "") + (f" --seed {args.seed}" if args.seed != 35 else "")
    text = tables(results, command)
    if args.results != "-":
        Path(args.results).parent.mkdir(parents=True, exist_ok=True)
        Path(args.results).write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
