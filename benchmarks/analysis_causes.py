"""How often ``cryod analyze`` names the right causes on records like real ones.

Run: PYTHONPATH=. python3 benchmarks/analysis_causes.py [--records N] [--processes 2] [--seed S] [--json PATH]
     [--only INDEXES] [--outputs DIR]

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
  cooler), each drawn the same way;
* the cooler's amplitude modulation and the cold end's drift, once per protocol;
* base model off: one parameter of the cryostat 10-30 % off the shipped
  model's (:data:`simulated_hw.hidden_effects.FAR_OFF_PARAMETERS`, set against
  the shipped model's value, not on top of the perturbation; the answer is
  ``base_model_off``);
* outside the catalogue: :data:`OUTSIDE_EFFECTS`, twice each (the answer is
  ``unexplained``, or ``none`` for an effect too small to matter), with the
  generic extension's held-out gain;
* the daemon's own records: ``cryod --simulate --sim-model MODEL`` (30 min of
  the daemon regulating at its configured setpoint with its feedforward) on a
  model file with one parameter 10-30 % off (the answer is ``base_model_off``),
  or with a disturbance of the model's generic kind (:data:`DAEMON_OUTSIDE`:
  an unrecorded heat load, a pickup; the answer is ``unexplained`` or ``none``).

Every record is analysed against the shipped model (``config/model.yaml``), as a
user would; a multiprocessing pool of ``--processes`` (2 at most) shares the
work. Printed: Markdown tables of the goals, per cause and protocol, the
records that failed and why, and the analysis times (wall and CPU; the machine
is shared).

With ``--outputs DIR`` each record's analysis is also written as ``cryod
analyze --no-figures`` writes it (``analysis.json``, the ``--json`` object;
``report.md``; the extended model) into ``DIR/record-NNN/``, with the SHA-256
of the columns analysed (``record.sha256``); the analysis is timed alone, as
without. Two runs, one on another checkout's code (``PYTHONPATH=OTHER_CHECKOUT
python3 benchmarks/analysis_causes.py ...``), are compared record by record by
``benchmarks/analysis_compare.py``.

Results: ``benchmarks/results/analysis_causes.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import multiprocessing
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from cryod.cli import use_one_blas_thread

use_one_blas_thread()          # one core per process: the machine has two (spawned workers run this too)

ROOT = Path(__file__).resolve().parent.parent
PROTOCOL_DURATIONS_S = {"identification": 3600.0, "pi_only": 1800.0, "feedforward": 1800.0}
PARAMETER_TOLERANCE = 0.2


def log_uniform(generator, low, high):
    """Log-uniform between ``low`` and ``high`` (a time constant's or an amplitude's size)."""
    return float(math.exp(generator.uniform(math.log(low), math.log(high))))


def either(generator, negative, positive):
    """Uniform over the union of two intervals, each drawn with its length's probability."""
    lengths = np.array([negative[1] - negative[0], positive[1] - positive[0]])
    low, high = negative if generator.random() < lengths[0] / lengths.sum() else positive
    return float(generator.uniform(low, high))


def draw_effect(cause: str, generator):
    """(changes for the model, {fitted parameter: true value}) of one effect of random size in its range."""
    from cryod.model import (
        DeadTime, HeatCapacityTemperature, HeaterNonlinearity, LinkDynamics, CoolerAmplitudeModulation,
        CoolerFrequencyDrift, CoolerHarmonic, PtcStageDrift, SensorLag,
    )

    if cause == "sensor_lag":
        tau = log_uniform(generator, *RANGES[cause]["flange_thermometer_time_constant_s"])
        return {"sensor_lag": SensorLag(tau)}, {"flange_thermometer_time_constant_s": tau}
    if cause == "link_dynamics":
        tau = log_uniform(generator, *RANGES[cause]["time_constant_s"])
        gain = float(generator.uniform(*RANGES[cause]["gain_factor"]))
        return {"link_dynamics": LinkDynamics(tau, gain)}, {"time_constant_s": tau, "gain_factor": gain}
    if cause == "dead_time":
        delay = log_uniform(generator, *RANGES[cause]["heater_to_flange_s"])
        return {"dead_time": DeadTime(delay)}, {"heater_to_flange_s": delay}
    if cause == "heat_capacity_temperature":
        exponent = either(generator, *RANGES[cause]["exponent"])
        return {"heat_capacity_temperature": HeatCapacityTemperature(exponent, 4.23)}, {"exponent": exponent}
    if cause == "heater_nonlinearity":
        k = either(generator, *RANGES[cause]["quadratic_coefficient_per_W"])
        return {"heater_nonlinearity": HeaterNonlinearity(k)}, {"quadratic_coefficient_per_W": k}
    if cause == "ptc_harmonics":
        order = int(generator.choice([2, 3]))
        amplitude = log_uniform(generator, *RANGES[cause]["amplitude_K"])
        phase = float(generator.uniform(-math.pi, math.pi))
        return ({"harmonics": (CoolerHarmonic(order, amplitude, phase),)},
                {f"order_{order}_amplitude_K": amplitude})
    if cause == "ptc_frequency_drift":
        if generator.random() < 0.5:
            rate = log_uniform(generator, *RANGES[cause]["rate_rad_s_per_hour"]) * float(generator.choice([-1, 1]))
            return {"ptc_frequency_drift": CoolerFrequencyDrift(rate)}, {"rate_rad_s_per_hour": rate}
        amplitude = float(generator.uniform(*RANGES[cause]["wander_fraction"])) * 10.83
        period = float(generator.uniform(*RANGES[cause]["wander_period_s"]))
        phase = float(generator.uniform(-math.pi, math.pi))
        return ({"ptc_frequency_drift": CoolerFrequencyDrift(0.0, amplitude, period, phase)},
                {"wander_amplitude_rad_s": amplitude, "wander_period_s": period})
    if cause == "ptc_amplitude_modulation":
        depth = float(generator.uniform(*RANGES[cause]["depth"]))
        period = float(generator.uniform(*RANGES[cause]["period_s"]))
        return ({"ptc_amplitude_modulation": CoolerAmplitudeModulation(depth, period, float(generator.uniform(-3, 3)))},
                {"depth": depth, "period_s": period})
    if cause == "ptc_stage_drift":
        rms = log_uniform(generator, *RANGES[cause]["rms_K"])
        coupling = float(generator.uniform(*RANGES[cause]["flange_coupling"]))
        return ({"ptc_stage_drift": PtcStageDrift(rms, float(generator.uniform(300.0, 1200.0)), coupling, 150.0,
                                                  int(generator.integers(0, 1000)))},
                {"flange_coupling": coupling})
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
    "ptc_amplitude_modulation": {"depth": (0.03, 0.2), "period_s": (300.0, 1200.0)},
    "ptc_stage_drift": {"rms_K": (0.5e-3, 3e-3), "flange_coupling": (0.3, 0.9)},
}
#: Catalogue causes of the new kind, each in every protocol: one-effect records beside the plan's.
NEW_CAUSES = ("ptc_amplitude_modulation", "ptc_stage_drift")


def plan(records: int, seed: int) -> list[dict]:
    """The records of the benchmark: kind, causes, protocol, seeds (about 1/5 clean, 1/2 one effect, the rest two)."""
    from simulated_hw.hidden_effects import EFFECT_GROUPS, FAR_OFF_PARAMETERS

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
    for protocol in protocols:
        for cause in NEW_CAUSES:
            jobs.append({"kind": "one effect", "causes": [cause], "protocol": protocol})
    for index in range(BASE_OFF_RECORDS):
        jobs.append({"kind": "base model off", "causes": [], "protocol": protocols[index % 3],
                     "off": FAR_OFF_PARAMETERS[index % len(FAR_OFF_PARAMETERS)]})
    for index, name in enumerate(OUTSIDE_EFFECTS):
        for repeat in range(2):
            jobs.append({"kind": "outside the catalogue", "causes": [], "protocol": protocols[(index + repeat) % 3],
                         "outside": name})
    for name in FAR_OFF_PARAMETERS:
        jobs.append({"kind": "base model off", "causes": [], "protocol": DAEMON, "off": name})
    for name in DAEMON_OUTSIDE:
        jobs.append({"kind": "outside the catalogue", "causes": [], "protocol": DAEMON, "outside": name})
    for index, job in enumerate(jobs):
        job["index"] = index
        job["seed"] = int(generator.integers(1, 2 ** 31))
    return jobs


#: Base models further off than the recalibration allows: records of a cryostat whose parameter is 10-30 % off
#: the shipped model's (a heater's power scale: every heater path; the flange's time constant; the line's gain on
#: T2; G2's time constant: :func:`simulated_hw.hidden_effects.far_off`), its other parameters off by up to 5 % as
#: in every record.
BASE_OFF_RECORDS = 12
FAR_OFF_RANGE = (0.10, 0.30)


def far_off(model, parameter: str, generator, reference):
    """``model`` with ``parameter`` 10-30 % either way off ``reference``'s (the shipped model's); returns (model,
    factor)."""
    from simulated_hw.hidden_effects import far_off as set_off

    factor = 1.0 + float(generator.choice([-1.0, 1.0])) * float(generator.uniform(*FAR_OFF_RANGE))
    return set_off(model, parameter, factor, reference), factor


def _outside(name: str, model, duration_s: float):
    """(model, make_record keyword arguments) of an effect outside the catalogue."""
    import dataclasses

    from cryod.model import TransferFunction

    if name == "extra flange mode":           # a sample stage hanging off the flange: a mode G1 does not have
        return dataclasses.replace(model, heater_to_flange=model.heater_to_flange
                                   + TransferFunction.first_order_lag(20.0, 0.4)), {}
    if name == "periodic heat load":          # a pump or a valve heating the flange every 400 s
        return model, {"unrecorded_heat_w": lambda t: 0.001 * (1.0 + math.sin(2.0 * math.pi * t / 400.0))}
    if name == "thermometer pickup":          # a 0.37 Hz vibration picked up by the flange thermometer's leads
        return model, {"flange_offset_K": lambda t: 20e-6 * np.sin(2.0 * math.pi * 0.37 * t)}
    from simulated_hw.hidden_effects import DISTURBANCES

    return model, DISTURBANCES[name](duration_s)


#: Effects outside the catalogue (the answer is ``unexplained``, or ``none`` when too small to matter).
OUTSIDE_EFFECTS = ("heat leak step", "slow heat load drift", "thermometer drift", "extra flange mode",
                   "periodic heat load", "thermometer pickup")
#: The daemon's own records: ``cryod --simulate --sim-model`` for this long.
DAEMON = "daemon"
DAEMON_DURATION_S = 1800.0
#: Disturbances put into the daemon's simulated cryostat (the model's generic kind).
DAEMON_OUTSIDE = ("daemon: unrecorded heat load", "daemon: flange thermometer pickup")


def _daemon_disturbance(name: str):
    from cryod.model import Disturbance, Pickup, SlowProcess

    if name == "daemon: unrecorded heat load":
        return Disturbance(unrecorded_heat=SlowProcess(1e-3, 600.0, 7))
    return Disturbance(pickups=(Pickup("flange", 0.37, 20e-6, 0.5),))


def daemon_record(model, folder: Path, seed: int) -> Path:
    """A record of the daemon (``cryod --simulate``, the example configuration) on a cryostat of ``model``."""
    import io

    from cryod.model import save_model
    from cryod.service.simulation import simulate

    model_path = folder / "simulated-cryostat.yaml"
    save_model(model, model_path)
    run = simulate(DAEMON_DURATION_S, sim_model=model_path, seed=seed, data_dir=folder / "data",
                   socket=folder / "control.sock", log_stream=io.StringIO())
    if run.exit_code != 0:
        raise RuntimeError(f"the simulated daemon stopped with {run.exit_code}: {run.summary.get('last_fault')}")
    if len(run.log_paths) > 1:          # the data log starts a file each day (and compresses the day before)
        raise RuntimeError(f"the simulated daemon's record crossed midnight and was split into {len(run.log_paths)} "
                           "day files; run the record again after midnight")
    return Path(run.log_paths[0])


def run_one(job: dict) -> dict:
    """Make one record and analyse it; returns what was found (a failure to make the record is reported as one)."""
    try:
        return _run_one(job)
    except Exception as error:                                   # reported as a failure, the run goes on
        return {**job, "truths": {}, "named": [], "cause": f"error: {error}", "reason": repr(error),
                "parameters": {}, "wall_s": 0.0, "cpu_s": 0.0}


def _run_one(job: dict) -> dict:
    from cryod.analysis.pipeline import analyze
    from cryod.analysis.record_data import RecordData, read_record_data
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
    unperturbed = model
    model, perturbation = perturbed_base(model, int(generator.integers(1, 2 ** 31)))
    protocol = job["protocol"]
    extra = {}
    if job.get("off"):
        model, truths["base_model_off"] = far_off(model, job["off"], generator, unperturbed)
    if protocol == DAEMON:
        if job.get("outside"):
            model = model.with_effects(disturbance=_daemon_disturbance(job["outside"]))
        with tempfile.TemporaryDirectory() as folder:
            data = read_record_data(daemon_record(model, Path(folder), int(generator.integers(1, 2 ** 31))))
    else:
        if job.get("outside"):
            model, extra = _outside(job["outside"], model, PROTOCOL_DURATIONS_S[protocol])
        record = make_record(model, protocol, duration_s=PROTOCOL_DURATIONS_S[protocol],
                             seed=int(generator.integers(1, 2 ** 31)), controller_model=shipped, **extra)
        data = RecordData.from_record(Record(record.metadata, record.columns, source=f"record {job['index']}"))
    started, cpu = time.perf_counter(), time.process_time()
    try:
        analysis = analyze(data, shipped)
    except Exception as error:                                   # reported as a failure, the run goes on
        return {**job, "truths": truths, "named": [], "cause": f"error: {error}", "reason": repr(error),
                "parameters": {}, "wall_s": time.perf_counter() - started, "cpu_s": time.process_time() - cpu}
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    if job.get("outputs"):
        write_outputs(analysis, data, shipped, Path(job["outputs"]) / f"record-{job['index']:03d}")
    named = {item.cause: _plain(item.fit.parameters) for item in analysis.causes} \
        if analysis.cause not in ("none", "unexplained") else {}
    generic = analysis.generic
    families = {item.family: item.score.explained_fraction for item in generic.families if item.score is not None} \
        if generic is not None else {}
    return {**job, "truths": truths, "named": list(named), "cause": analysis.cause,
            "generic_used": list(generic.used) if generic is not None else [],
            "generic_removed": generic.score.explained_fraction if generic is not None else None,
            "generic_families": families, "at_tolerance_within": _at_tolerance(analysis),
            "reason": analysis.decision.reason, "parameters": named, "wall_s": wall, "cpu_s": cpu,
            "gain": analysis.decision.gain.ratio, "recalibrated": analysis.recalibrated,
            "perturbation": perturbation,
            "generic_gain": generic.score.gain.ratio if generic is not None else None,
            "generic_added": bool(generic is not None and generic.added),
            "remaining": bool(analysis.remaining is not None and analysis.remaining.present)}


def write_outputs(analysis, data, shipped, folder: Path) -> None:
    """What ``cryod analyze --no-figures`` writes for ``analysis`` (of ``data`` against ``shipped``), into
    ``folder``, and the SHA-256 of the columns analysed (a difference between two runs then says whether the
    record or its analysis differed). The command's writer is handed the analysis already made (its own call of
    ``analyze`` answers with it), so the record is analysed once."""
    from unittest import mock

    import cryod.cli.analyze as command

    folder.mkdir(parents=True, exist_ok=True)
    digest = hashlib.sha256()
    for column in (data.time_s, data.flange_K, data.ptc_stage_K, data.heater_w, data.setpoint_K,
                   data.heater_change_s):
        if column is not None:
            digest.update(np.ascontiguousarray(column, dtype=float).tobytes())
    (folder / "record.sha256").write_text(digest.hexdigest() + "\n", encoding="utf-8")
    with mock.patch.object(command, "analyze", lambda *_: analysis):
        command.analyse_and_write(data, shipped, Path(f"{folder.name}.csv"), ROOT / "config" / "model.yaml", folder,
                                  figures=False)


def _at_tolerance(analysis) -> list[str]:
    beyond = analysis.beyond_recalibration
    if beyond is not None:
        return list(beyond.at_tolerance)
    recalibration = analysis.final_recalibration or analysis.recalibration
    return [row.parameter for row in recalibration.table() if row.at_tolerance] if recalibration else []


def _plain(parameters: dict) -> dict:
    return {name: (float(value) if isinstance(value, (int, float, np.floating)) else value)
            for name, value in parameters.items()}


def judged(result: dict) -> dict:
    """Right or wrong, and each true parameter's relative error (a base model far off: ``base_model_off``;
    an effect outside the catalogue: no catalogue cause)."""
    if str(result["cause"]).startswith("error:"):
        return {"right": False, "errors": {}, "parameters_within": False, "wrong_cause": False}
    truths = dict(result["truths"])
    catalogue = [cause for cause in result["named"]]
    wrong_cause = bool(set(catalogue) - set(truths)) or (result["cause"] == "base_model_off"
                                                          and "base_model_off" not in truths)
    if result["kind"] == "base model off":
        right = result["cause"] == "base_model_off" and not set(catalogue)
        return {"right": right, "errors": {}, "parameters_within": right, "wrong_cause": wrong_cause}
    if result["kind"] == "outside the catalogue":
        right = result["cause"] in ("unexplained", "none")
        return {"right": right, "errors": {}, "parameters_within": right, "wrong_cause": wrong_cause}
    right = sorted(result["named"]) == sorted(truths) and result["cause"] != "base_model_off"
    errors = {}
    for cause, truth in truths.items():
        fitted = result["parameters"].get(cause, {})
        for name, true in truth.items():
            value = fitted.get(name)
            errors[f"{cause}.{name}"] = abs(value - true) / abs(true) if value is not None else math.inf
    within = right and all(error <= PARAMETER_TOLERANCE for error in errors.values())
    return {"right": right, "errors": errors, "parameters_within": within, "wrong_cause": wrong_cause}


def tables(results: list[dict]) -> str:
    """The Markdown tables of the benchmark."""
    lines = []
    by_kind = defaultdict(list)
    for result in results:
        by_kind[result["kind"]].append((result, judged(result)))
    goals = {"clean": ("`none`", 0.97), "one effect": ("cause named right", 0.97),
             "two effects": ("both causes named, nothing else", 0.90),
             "base model off": ("`base_model_off`", 1.0),
             "outside the catalogue": ("`unexplained` or `none`, no catalogue cause", 0.97)}
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
    wrong = sum(judged(result)["wrong_cause"] for result in results)
    lines += ["", f"A wrong catalogue cause (or `base_model_off` where the base model is not far off) in {wrong} "
                  f"of {len(results)} records ({100.0 * wrong / max(len(results), 1):.1f} %; goal at most 3 %)."]
    lines += ["", "| effect | protocol | verdict | discrepancy left | generic families used | removes | "
                  "held-out gain | added | each family alone removes |",
              "|---|---|---|---|---|---|---|---|---|"]
    for result in results:
        if result["kind"] in ("outside the catalogue", "base model off"):
            what = result.get("outside") or (f"base model off: {result.get('off')} "
                                             f"x{result['truths'].get('base_model_off', 1):.2f}")
            gain, removed = result.get("generic_gain"), result.get("generic_removed")
            alone = ", ".join(f"{family} {100.0 * fraction:.0f} %" for family, fraction in
                              sorted(result.get("generic_families", {}).items(), key=lambda item: -item[1]))
            lines.append(f"| {what} | {result['protocol']} | {', '.join(result['named']) or result['cause']} | "
                         f"{'yes' if result.get('remaining') else 'no'} | "
                         f"{' + '.join(result.get('generic_used', [])) or '-'} | "
                         f"{'-' if removed is None else f'{100.0 * removed:.1f} %'} | "
                         f"{'-' if gain is None else f'{gain:.3g}'} | {'yes' if result.get('generic_added') else 'no'} | "
                         f"{alone or '-'} |")
    lines += ["", "| kind | records | verdict right | generic extension added | its held-out gain: median (least, "
                  "most) | families used |", "|---|---|---|---|---|---|"]
    kinds = defaultdict(list)
    for result in results:
        if result["kind"] in ("outside the catalogue", "base model off"):
            kinds[result.get("outside") or f"base model off: {result.get('off')}"].append(result)
    for kind, items in kinds.items():
        gains = [item["generic_gain"] for item in items if item.get("generic_added")]
        used = defaultdict(int)
        for item in items:
            for family in item.get("generic_used", []) if item.get("generic_added") else []:
                used[family] += 1
        spread = (f"{np.median(gains):.3g} ({min(gains):.3g}, {max(gains):.3g})" if gains else "-")
        lines.append(f"| {kind} | {len(items)} | {sum(judged(item)['right'] for item in items)} | "
                     f"{sum(bool(item.get('generic_added')) for item in items)} | {spread} | "
                     f"{', '.join(f'{family} ({count})' for family, count in used.items()) or '-'} |")
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
            if not isinstance(truth, dict):
                continue
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
    slowest = sorted(results, key=lambda item: -item["cpu_s"])[:3]
    lines += ["", "The slowest three (CPU): " + "; ".join(
        f"record {item['index']} ({item['kind']}, {item['protocol']}, {' + '.join(item['causes']) or item.get('outside') or item.get('off') or 'clean'}) "
        f"{item['cpu_s']:.1f} s" for item in slowest) + "."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=110, help="records in all (default 110)")
    parser.add_argument("--processes", type=int, default=2, help="worker processes, at most 2 (default 2)")
    parser.add_argument("--seed", type=int, default=12, help="seed of the plan (default 12)")
    parser.add_argument("--json", default=None, help="also write every result to this JSON file")
    parser.add_argument("--only", default=None, metavar="INDEXES",
                        help="run only these records of the plan (comma-separated indexes)")
    parser.add_argument("--outputs", default=None, metavar="DIR",
                        help="also write each record's cryod analyze outputs (no figures) into DIR/record-NNN/")
    args = parser.parse_args()
    jobs = plan(args.records, args.seed)
    if args.only:
        wanted = {int(index) for index in args.only.split(",")}
        jobs = [job for job in jobs if job["index"] in wanted]
    if args.outputs:
        jobs = [{**job, "outputs": str(Path(args.outputs).resolve())} for job in jobs]
    processes = max(1, min(args.processes, 2))
    results = []
    started = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(processes) as pool:
        for result in pool.imap_unordered(run_one, jobs):
            results.append(result)
            if args.json:                 # written as the results come: a run cut short keeps what it found
                Path(args.json).write_text(json.dumps(sorted(results, key=lambda item: item["index"]), indent=1,
                                                      default=str) + "\n", encoding="utf-8")
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
