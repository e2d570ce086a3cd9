"""Are the identified uncertainties honest? Coverage of the 2-sigma intervals over simulated commissioning runs.

Run: PYTHONPATH=. python3 benchmarks/identify_coverage.py [--records 50] [--processes 2] [--bootstrap 30]

Each record is one ``cryod identify --acquire --simulate`` experiment with the
default plan (120 s line hold, 10 mW step held until settled) through the
daemon on the simulated cryostat (the shipped model, virtual clock, its own
noise seed), fitted by :func:`cryod.identification.model_fit.identify_model`
with the printed model as the base. For every stated parameter the truth is
compared with the 2-sigma interval; the coverage should be about 95 %.

The truth is the simulated cryostat's model: the terms of G2 G1 and G3 from its
partial fractions, the line gain from its transfer functions, the operating
point, the cooler's frequency, and the line's amplitude as the DMMs read it (a
1 PLC integration at 50 Hz averages the 1.72 Hz line to sin(x)/x of it,
x = w / (2 x 50 Hz): 0.998). The line's phase is left out: it refers to the
record's first instant, which the daemon's clock, not the model, sets.

Also reported: the largest relative error of the time constants and gains
(goal: within 1 %), and how often each number of terms was chosen.

Results: ``benchmarks/results/identify_coverage.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing
import tempfile
import time
from pathlib import Path

import numpy as np

from cryod.cli import use_one_blas_thread

use_one_blas_thread()          # one core per process: the machine has two, shared (spawned workers run this too)

ROOT = Path(__file__).resolve().parent.parent


def truth(model) -> dict[str, float]:
    """The parameters of ``model`` in the names of the identified model's uncertainty section."""
    from cryod.model.uncertainty import line_gain_of

    values = {}
    for path, function in (("heater_to_thermometer", model.heater_to_thermometer),
                           ("heater_to_ptc_stage", model.heater_to_ptc_stage)):
        form = function.modal_form()
        terms = sorted((-1.0 / float(p.real), float((r * -1.0 / p).real)) for p, r in zip(form.poles, form.residues))
        for index, (tau, gain) in enumerate(terms, start=1):
            values[f"{path}.time_constant_s.{index}"] = tau
            values[f"{path}.gain_K_per_W.{index}"] = gain
    gain = line_gain_of(model)
    values["ptc_line.T2_over_T5_real"] = gain.real
    values["ptc_line.T2_over_T5_imaginary"] = gain.imag
    values["operating_point.flange_temperature_K"] = model.operating_point.flange_temperature_K
    values["operating_point.ptc_stage_temperature_K"] = model.operating_point.ptc_stage_temperature_K
    values["ptc.angular_frequency_rad_s"] = model.ptc.angular_frequency_rad_s
    x = model.ptc.angular_frequency_rad_s / (2.0 * 50.0)          # half the 20 ms integration times omega
    values["ptc.ptc_stage_amplitude_K"] = model.ptc.ptc_stage_amplitude_K * math.sin(x) / x
    return values


def one_record(job: tuple[int, int]) -> dict:
    """Acquire and fit one record with noise seed ``seed``."""
    seed, bootstrap = job
    from cryod.analysis.record_data import RecordData
    from cryod.config import EXAMPLE_CONFIG_PATH, load_config
    from cryod.cli.acquire import acquire
    from cryod.identification.experiment import ExperimentPlan
    from cryod.identification.model_fit import identify_model
    from cryod.model import load_model
    from cryod.records.record import read_record
    from drivers.clock import VirtualClock
    from cryod.service.simulation import SimulatedInstrumentsOpener

    simulated = load_model(ROOT / "config" / "model.yaml")
    base = load_model(ROOT / "config" / "model-paper-printed.yaml")
    with tempfile.TemporaryDirectory() as directory:
        directory = Path(directory)
        config = load_config(EXAMPLE_CONFIG_PATH)
        config = dataclasses.replace(
            config, data=dataclasses.replace(config.data, directory=directory / "data"),
            control_socket=dataclasses.replace(config.control_socket, path=directory / "c.sock"),
            simulation=dataclasses.replace(config.simulation, transport="in-process", seed=seed))
        started = time.perf_counter()
        acquisition = acquire(config, ExperimentPlan(), SimulatedInstrumentsOpener(simulated, seed), VirtualClock(),
                              install_signal_handlers=False, progress=False)
        acquired = time.perf_counter() - started
        records = [RecordData.from_record(read_record(path)) for path in acquisition.record_paths]
    started = time.perf_counter()
    result = identify_model(records, base, replicates=bootstrap, seed=seed)
    fitted = time.perf_counter() - started
    stated = result.uncertainty
    return {"seed": seed, "outcome": acquisition.outcome, "step_s": acquisition.runner.phase_log[-1][2]
            - acquisition.runner.phase_log[-1][1], "acquire_s": acquired, "fit_s": fitted,
            "terms": [result.flange.fit.count, result.stage.fit.count],
            "values": dict(zip(stated.names, stated.values)),
            "sigmas": dict(zip(stated.names, stated.standard_uncertainties)),
            "bootstrap_ratio": result.bootstrap_ratio}


def summarise(results: list[dict], expected: dict[str, float]) -> dict:
    names = [name for name in expected if all(name in r["values"] for r in results)]
    per_parameter = {}
    inside_all = []
    worst_relative = {}
    for name in names:
        errors = np.array([r["values"][name] - expected[name] for r in results])
        sigmas = np.array([r["sigmas"][name] for r in results])
        inside = np.abs(errors) <= 2.0 * sigmas
        inside_all.extend(inside.tolist())
        ratio = [r["bootstrap_ratio"].get(name) for r in results if r["bootstrap_ratio"].get(name) is not None]
        per_parameter[name] = {
            "truth": expected[name], "coverage_2_sigma": float(inside.mean()),
            "mean_error_in_sigma": float(np.mean(errors / sigmas)),
            "rms_error_in_sigma": float(np.sqrt(np.mean((errors / sigmas) ** 2))),
            "largest_relative_error": float(np.max(np.abs(errors / expected[name]))) if expected[name] else None,
            "median_bootstrap_over_covariance": float(np.median(ratio)) if ratio else None,
        }
        if "time_constant" in name or "gain_K_per_W" in name:
            worst_relative[name] = per_parameter[name]["largest_relative_error"]
    return {"records": len(results), "parameters": len(names), "checks": len(inside_all),
            "coverage_2_sigma": float(np.mean(inside_all)),
            "largest_relative_error_time_constants_and_gains": max(worst_relative.values()),
            "terms_chosen": {f"{a}+{b}": sum(1 for r in results if r["terms"] == [a, b])
                             for a, b in sorted({tuple(r["terms"]) for r in results})},
            "step_hold_s": [float(np.min([r["step_s"] for r in results])),
                            float(np.max([r["step_s"] for r in results]))],
            "seconds_per_record": {"acquire": float(np.mean([r["acquire_s"] for r in results])),
                                   "fit": float(np.mean([r["fit_s"] for r in results]))},
            "per_parameter": per_parameter}


def table(summary: dict) -> str:
    lines = ["| parameter | truth | 2-sigma coverage | mean error / sigma | rms error / sigma | largest relative error "
             "| bootstrap / covariance (median) |", "|---|---|---|---|---|---|---|"]
    for name, row in summary["per_parameter"].items():
        relative = row["largest_relative_error"]
        boot = row["median_bootstrap_over_covariance"]
        lines.append(f"| {name} | {row['truth']:.6g} | {100 * row['coverage_2_sigma']:.0f} % | "
                     f"{row['mean_error_in_sigma']:+.2f} | {row['rms_error_in_sigma']:.2f} | "
                     f"{f'{100 * relative:.3f} %' if relative is not None else '-'} | "
                     f"{f'{boot:.2f}' if boot is not None else '-'} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=50)
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--bootstrap", type=int, default=30)
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument("--json", type=Path, default=None, help="also write every record's result here")
    args = parser.parse_args()
    from cryod.model import load_model

    expected = truth(load_model(ROOT / "config" / "model.yaml"))
    seeds = np.random.default_rng(args.first_seed).integers(0, 2 ** 31, size=args.records)
    started = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(min(args.processes, 2)) as pool:
        results = pool.map(one_record, [(int(seed), args.bootstrap) for seed in seeds], chunksize=1)
    finished = [r for r in results if r["outcome"] == "finished"]
    summary = summarise(finished, expected)
    summary["wall_s"] = time.perf_counter() - started
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "records": results}, indent=1))
    print(json.dumps({key: value for key, value in summary.items() if key != "per_parameter"}, indent=1))
    print()
    print(table(summary))


if __name__ == "__main__":
    main()
