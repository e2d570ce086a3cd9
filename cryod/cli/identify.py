"""``cryod identify RECORD [RECORD...] --out MODEL.yaml`` and ``cryod identify --acquire [--simulate] --out MODEL.yaml``.

Fits the model's transfer functions, operating point and cooler line to the
records, with the number of first-order terms of each heater path chosen from
the data and every parameter's uncertainty
(:mod:`cryod.identification.model_fit`), and writes a model file that
:func:`cryod.model.load_model` reads (with its ``uncertainty`` section). An
existing file is not overwritten unless ``--force`` is given, a record or the
base model never, and in the report's directory only the files cryod wrote
there itself are replaced (:mod:`cryod.output_files`; checked before anything
is measured).

``--acquire`` first runs the identification experiment on the cryostat
through the daemon (:mod:`cryod.cli.acquire`; ``--simulate``: on
the simulated cryostat), then fits the record it wrote. ``--report DIR``
(the default with ``--acquire``: ``<model>-report``) writes the figures and a
markdown report: the model, its uncertainties, the feedforward's limit at the
setpoint with its range, and the PI gains ``cryod tune`` suggests.

Exit status: 0 done; 2 a record, the base model, the configuration, the plan
or the output path cannot be used; 1 the records do not support the fit (what
is missing is named); with ``--acquire``, when the experiment did not finish:
130 interrupted (Ctrl-C, SIGTERM), or the exit code of the fault that stopped
it (docs/how-to/commission.md). The record is kept in every case.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
from pathlib import Path

from cryod.analysis.record_data import analysed_stretch, read_record_data
from cryod.analysis.summary import plain
from cryod.argument_types import not_negative, number, positive, setpoint_list, speed
from cryod.cli.output_files import listed_when_written
from cryod.identification.experiment import ExperimentPlan
from cryod.identification.fit import IdentificationError
from cryod.identification.model_fit import ModelIdentification, identify_model
from cryod.identification.record_check import describe, record_problems
from cryod.identification.uncertainty import BOOTSTRAP_REPLICATES
from cryod.model import DEFAULT_MODEL_PATH, load_model, save_model
from cryod.output_files import OutputFiles, output_file_refusal
from cryod.records.record import RecordFormatError
from cryod.yaml_source import FileFormatError

PROGRAM = "cryod identify"
ACQUIRE_DIRECTORY = Path("cryod-identify")


def configure_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Arguments of ``cryod identify``."""
    parser.description = ("Fit the cryostat model (heater to T2 and T5 as sums of first-order terms, their number "
                          "chosen from the data; the cooler line's path to T2; operating point; sensor noise) to "
                          "measured records, with every parameter's uncertainty, and write a model file. With "
                          "--acquire, first run the identification experiment through the daemon.")
    parser.add_argument("records", nargs="*", help="records of one cryostat (cryod-log v1 CSV); none with --acquire")
    parser.add_argument("--base", default=str(DEFAULT_MODEL_PATH),
                        help="model to start from; also gives the PTC heat capacity (default: the shipped model)")
    parser.add_argument("--out", required=True, help="model file to write (YAML)")
    parser.add_argument("--force", action="store_true", help="overwrite --out if it exists")
    parser.add_argument("--no-harmonics", action="store_true", help="do not put T5's harmonics into the model")
    parser.add_argument("--max-terms", type=int, default=4, metavar="N",
                        help="most first-order terms tried for each heater path (default 4)")
    parser.add_argument("--bootstrap", type=int, default=BOOTSTRAP_REPLICATES, metavar="N",
                        help=f"block-bootstrap refits checking the uncertainties (default {BOOTSTRAP_REPLICATES}; "
                             "0: the fit's covariance only)")
    parser.add_argument("--max-duration", type=not_negative, default=0.0, metavar="S",
                        help="fit only the stretch of S seconds of each record where the heater moves most (bounds "
                             "time and memory on day-long records; default 0: every record whole)")
    parser.add_argument("--report", default=None, metavar="DIR",
                        help="write figures and report.md here (default with --acquire: <out>-report)")
    parser.add_argument("--no-figures", action="store_true", help="report without figures")
    parser.add_argument("--no-tune", action="store_true", help="report without the cryod tune suggestion (faster)")
    parser.add_argument("--setpoint", type=number, default=None, metavar="K",
                        help="setpoint for the report's feedforward limit and PI gains (default: the configuration's)")
    parser.add_argument("--config", type=Path, default=None, metavar="PATH",
                        help="daemon configuration: instruments, heater, safety, data (default /etc/cryod/cryod.yaml; "
                             "with --simulate or without --acquire the example config/cryod.yaml)")
    parser.add_argument("--json", action="store_true", help="print a summary as one JSON object on stdout")
    acquire = parser.add_argument_group("the experiment (--acquire)")
    acquire.add_argument("--acquire", action="store_true",
                         help="run the identification experiment through the daemon first, then fit its record")
    acquire.add_argument("--simulate", action="store_true", help="on the simulated cryostat (cryod --simulate's bench)")
    acquire.add_argument("--speed", type=speed, default="max",
                         help="with --simulate: simulated seconds per real second, or 'max' (default: virtual time)")
    acquire.add_argument("--sim-model", type=Path, default=None, help="with --simulate: the simulated cryostat's model")
    acquire.add_argument("--seed", type=int, default=None, help="with --simulate: sensor-noise seed")
    acquire.add_argument("--data-dir", type=Path, default=None,
                         help="where the record goes (default: the configuration's; with --simulate "
                              "./cryod-identify/data)")
    acquire.add_argument("--socket", type=Path, default=None,
                         help="control socket while the experiment runs (default: the configuration's; with "
                              "--simulate ./cryod-identify/control.sock)")
    defaults = ExperimentPlan()
    acquire.add_argument("--setpoints", type=setpoint_list, default=None, metavar="K,K,...",
                         help="identify about each of these setpoints in turn, in closed loop (regulate, hold, a "
                              "setpoint step), one model each, a zone each: --out is then a folder, given "
                              "model-<K>K.yaml per setpoint (docs/how-to/zones.md, Zones)")
    acquire.add_argument("--setpoint-step", type=number, default=defaults.setpoint_step_K, metavar="K",
                         help=f"with --setpoints: the setpoint step about each (default {defaults.setpoint_step_K:g} K)")
    acquire.add_argument("--step-power", type=positive, default=defaults.step_power_w, metavar="W",
                         help=f"size of the heater step (default {defaults.step_power_w:g} W)")
    acquire.add_argument("--base-power", type=not_negative, default=defaults.base_power_w, metavar="W",
                         help="heater power before the step (default 0: the zero-heater operating point)")
    acquire.add_argument("--line-hold", type=positive, default=defaults.line_hold_s, metavar="S",
                         help=f"open-loop hold before the step, for the cooler's line (default {defaults.line_hold_s:g} s)")
    acquire.add_argument("--settle-fraction", type=positive, default=defaults.settle_fraction, metavar="F",
                         help="settled when T2 moves less than this fraction of its change over the settle window "
                              f"(default {defaults.settle_fraction:g})")
    acquire.add_argument("--settle-window", type=positive, default=defaults.settle_window_s, metavar="S",
                         help=f"the settle window (default {defaults.settle_window_s:g} s)")
    acquire.add_argument("--min-settle", type=not_negative, default=defaults.min_settle_s, metavar="S",
                         help=f"shortest settling phase (default {defaults.min_settle_s:g} s)")
    acquire.add_argument("--max-settle", type=positive, default=defaults.max_settle_s, metavar="S",
                         help=f"longest settling phase; then it ends unsettled, and says so "
                              f"(default {defaults.max_settle_s:g} s)")
    acquire.add_argument("--modulation-amplitude", type=not_negative, default=0.0, metavar="W",
                         help="heater modulation about the stepped power after settling (default 0: none)")
    acquire.add_argument("--modulation-frequency", type=positive, default=defaults.modulation_rad_s, metavar="RAD_S",
                         help=f"its angular frequency (default {defaults.modulation_rad_s:g} rad/s)")
    acquire.add_argument("--modulation-time", type=positive, default=defaults.modulation_s, metavar="S",
                         help=f"its length (default {defaults.modulation_s:g} s)")
    return parser


def summary(result: ModelIdentification, out: Path) -> dict:
    """The printed summary (keys of the earlier summary kept; uncertainties added)."""
    model = result.model
    derived = result.derived()
    stated = result.uncertainty
    flange, stage = result.flange.fit, result.stage.fit
    return plain({
        "model": str(out),
        "heater_to_thermometer_terms": flange.count,
        "heater_to_thermometer_time_constants_s": [float(t) for t in flange.time_constants_s],
        "heater_to_thermometer_dc_gain_K_per_W": derived["heater_to_thermometer_dc_gain_K_per_W"][0],
        "heater_to_thermometer_dc_gain_uncertainty_K_per_W": derived["heater_to_thermometer_dc_gain_K_per_W"][1],
        "heater_to_ptc_stage_terms": stage.count,
        "heater_to_ptc_stage_gain_K_per_W": derived["heater_to_ptc_stage_dc_gain_K_per_W"][0],
        "heater_to_ptc_stage_gain_uncertainty_K_per_W": derived["heater_to_ptc_stage_dc_gain_K_per_W"][1],
        "heater_to_ptc_stage_time_constant_s": float(stage.time_constants_s[-1]),
        "ptc_line_gain_T2_over_T5": derived["ptc_line_gain_T2_over_T5"][0],
        "ptc_line_T2_lag_behind_T5_rad": derived["ptc_line_T2_lag_behind_T5_rad"][0],
        "ptc_line_T2_lag_uncertainty_rad": derived["ptc_line_T2_lag_behind_T5_rad"][1],
        "operating_point_K": dataclasses.asdict(model.operating_point),
        "ptc_angular_frequency_rad_s": model.ptc.angular_frequency_rad_s,
        "ptc_stage_amplitude_K": model.ptc.ptc_stage_amplitude_K,
        "noise_rms_K": list(result.noise_rms_K),
        "residual_rms_in_noise": [list(pair) for pair in result.residual_rms_in_noise],
        "parameters": {name: {"value": value, "standard_uncertainty": sigma,
                              "bootstrap_over_covariance": result.bootstrap_ratio.get(name)}
                       for name, value, sigma in zip(stated.names, stated.values, stated.standard_uncertainties)},
        "term_selection": {"heater_to_thermometer": result.flange.selection.table,
                           "heater_to_ptc_stage": result.stage.selection.table},
    })


def _plan(args) -> ExperimentPlan:
    return ExperimentPlan(step_power_w=args.step_power, base_power_w=args.base_power, line_hold_s=args.line_hold,
                          settle_fraction=args.settle_fraction, settle_window_s=args.settle_window,
                          min_settle_s=args.min_settle, max_settle_s=args.max_settle,
                          modulation_amplitude_w=args.modulation_amplitude,
                          modulation_rad_s=args.modulation_frequency, modulation_s=args.modulation_time,
                          setpoint_step_K=getattr(args, "setpoint_step", ExperimentPlan.setpoint_step_K))


def _config_path(args) -> Path:
    from cryod.config import EXAMPLE_CONFIG_PATH
    from cryod.service.discovery import SERVICE_CONFIG as DEFAULT_CONFIG

    if args.config is not None:
        return args.config
    return DEFAULT_CONFIG if args.acquire and not args.simulate else EXAMPLE_CONFIG_PATH


def _acquire(args, config, base, plan: ExperimentPlan | None = None) -> tuple[int, object]:
    """Run the experiment (``plan``, or the command line's); (exit status, Acquisition or None)."""
    from cryod.cli.acquire import acquire
    from cryod.service.logs import ServiceLogging
    from drivers.clock import MonotonicClock, clock_for_speed

    plan = plan or _plan(args)
    try:
        plan.check(config.heater.max_power_w)
    except ValueError as error:
        print(f"{PROGRAM}: the experiment cannot run on this heater: {error}", file=sys.stderr)
        return 2, None
    taus = base.heater_to_thermometer.time_constants_s
    expected = 5.0 * max(taus) if taus else 900.0
    metadata = {"identify_base_model": str(args.base)}
    if args.simulate:
        from cryod.service.simulation import DryRunOptions, SimulatedInstrumentsOpener, simulation_config

        overrides = DryRunOptions(speed=args.speed, seed=args.seed,
                                  data_dir=args.data_dir or ACQUIRE_DIRECTORY / "data",
                                  socket=args.socket or ACQUIRE_DIRECTORY / "control.sock")
        try:
            config = simulation_config(overrides, config)
            simulated = load_model(args.sim_model or config.simulation.model or DEFAULT_MODEL_PATH)
        except (ValueError, FileFormatError) as error:
            print(f"{PROGRAM}: {error}", file=sys.stderr)
            return 2, None
        opener, claims = SimulatedInstrumentsOpener(simulated, config.simulation.seed), None
        clock = clock_for_speed(args.speed)
        metadata.update({"simulated": "yes (cryod identify --acquire --simulate)",
                         "simulated_model": str(args.sim_model or config.simulation.model or DEFAULT_MODEL_PATH),
                         "simulation_seed": config.simulation.seed})
    else:
        from cryod.service.instruments import (
            check_calibrations,
            check_instrument_locking,
            instrument_addresses,
            open_instruments,
        )

        problem = check_calibrations(config) or check_instrument_locking(config)
        if problem:
            print(f"{PROGRAM}: {problem}", file=sys.stderr)
            return 2, None
        if args.data_dir is not None or args.socket is not None:
            config = dataclasses.replace(
                config, data=dataclasses.replace(config.data, directory=args.data_dir or config.data.directory),
                control_socket=dataclasses.replace(config.control_socket,
                                                   path=args.socket or config.control_socket.path))
        opener, clock = open_instruments, MonotonicClock()
        claims = instrument_addresses
    logging_service = ServiceLogging(level=logging.WARNING)
    logging_service.start()
    try:
        acquisition = acquire(config, plan, opener, clock, metadata=metadata, expected_settle_s=expected,
                              instrument_addresses=claims)
    finally:
        logging_service.stop()
    print(f"{PROGRAM}: {acquisition.message}", file=sys.stderr)
    if acquisition.outcome != "finished":
        if acquisition.record_paths:
            print(f"{PROGRAM}: no model was fitted; to fit what was recorded: cryod identify "
                  f"{' '.join(map(str, acquisition.record_paths))} --out {args.out}", file=sys.stderr)
        return acquisition.exit_code, acquisition
    return 0, acquisition


def _tuning_text(model, setpoint_K: float, config) -> str:
    from cryod.cli.tune import PAPER_GAINS, report
    from cryod.control.tuning import TuningError, step_performance, suggest_gains

    heater_max_w = config.heater.max_power_w
    options = {"period_s": config.loop.period_s}
    try:
        tuning = suggest_gains(model, setpoint_K, heater_max_w, **options)
        configured = step_performance(model, config.control.term("pi"), setpoint_K, heater_max_w, **options)
        paper = step_performance(model, PAPER_GAINS, setpoint_K, heater_max_w, **options)
    except TuningError as error:
        return f"cryod tune found no gains: {error}"
    rows = (("suggested", tuning.best), (f"configuration ({Path(config.source).name})", configured),
            ("paper (Kp 80, I 4 as W/K, W/(K s))", paper))
    from cryod.control.tuning import Tolerances

    return report(rows, Tolerances(), tuning.best.start_K, setpoint_K)


def run(args: argparse.Namespace) -> int:
    """Run the identification (and the experiment first with --acquire); returns the exit status."""
    from cryod.config import load_config

    out = Path(args.out)
    inputs = [Path(path) for path in args.records] + [Path(args.base)]
    series = getattr(args, "setpoints", None) is not None       # --out is a folder of models: checked per model
    refusal = None if series else output_file_refusal(PROGRAM, out, force=args.force, inputs=inputs)
    report_dir = args.report or (f"{out.with_suffix('')}-report" if args.acquire and not series else None)
    report_files = None
    if series and args.report:
        refusal = "--report is for one model; with --setpoints each model's fit is summarised on the terminal"
    if refusal is None and report_dir is not None:
        report_files = _report_files(args, Path(report_dir), max(len(args.records), 1), inputs)
        refusal = report_files.refusal(force=args.force)
    if refusal is not None:
        print(f"{PROGRAM}: {refusal}", file=sys.stderr)
        return 2
    if args.acquire and args.records:
        print(f"{PROGRAM}: --acquire records its own data: give no records with it", file=sys.stderr)
        return 2
    if not args.acquire and not args.records:
        print(f"{PROGRAM}: give the records to fit, or --acquire to run the experiment", file=sys.stderr)
        return 2
    if args.simulate and not args.acquire:
        print(f"{PROGRAM}: --simulate runs the experiment on the simulated cryostat: it needs --acquire",
              file=sys.stderr)
        return 2
    if args.max_terms < 1 or args.bootstrap < 0:
        print(f"{PROGRAM}: --max-terms must be at least 1 and --bootstrap at least 0", file=sys.stderr)
        return 2
    config_path = _config_path(args)
    try:
        base = load_model(args.base)
        config = load_config(config_path)
    except FileFormatError as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    acquisition = None
    record_paths = [Path(p) for p in args.records]
    if getattr(args, "setpoints", None) is not None:
        return _run_series(args, config, base, out)
    if args.acquire:
        status, acquisition = _acquire(args, config, base)
        if status != 0:
            return status
        record_paths = list(acquisition.record_paths)
        if report_files is not None and len(record_paths) > 1:      # a day's end cut the record: more figures
            report_files = _report_files(args, Path(report_dir), len(record_paths), inputs + record_paths)
            refusal = report_files.refusal(force=args.force)
            if refusal is not None:
                print(f"{PROGRAM}: {refusal}; the records are kept: {' '.join(map(str, record_paths))}",
                      file=sys.stderr)
                return 2
    try:
        records = [read_record_data(path) for path in record_paths]
    except (RecordFormatError, FileFormatError) as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    stretches = [analysed_stretch(data, getattr(args, "max_duration", 0.0)) for data in records]
    for path, data, part in zip(record_paths, records, stretches):
        if part is not data:
            print(f"{PROGRAM}: {path}: {part.notes[-1].replace('analysed', 'fitted', 1)}", file=sys.stderr)
    records = stretches
    found_per_record = [record_problems(data, base) for data in records]
    if any(not any(p.startswith("no heater step") for p in found) for found in found_per_record):
        # another record has the step: one without (a hold for the line) only adds to the fit
        found_per_record = [[p for p in found if not p.startswith("no heater step")] for found in found_per_record]
    # records in time order: one cut short by the next (a daily file at UTC midnight) is not judged alone
    found_per_record = [[p for p in found if not (index < len(records) - 1 and p.startswith("the record holds"))]
                        for index, found in enumerate(found_per_record)]
    problems = [describe(str(path), found) for path, found in zip(record_paths, found_per_record) if found]
    if problems:
        for problem in problems:
            print(f"{PROGRAM}: {problem}", file=sys.stderr)
        return 1
    try:
        result = identify_model(records, base, harmonics=not args.no_harmonics, max_terms=args.max_terms,
                                replicates=args.bootstrap)
    except (IdentificationError, ValueError, ArithmeticError) as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 1
    names = ", ".join(map(str, record_paths))
    model = dataclasses.replace(result.model, name=f"identified from {len(records)} record(s)",
                                description=f"Identified by cryod identify from {names}, starting from {args.base}.")
    result.model = model
    header = "\n".join([f"Written by cryod identify from: {names}", f"Base model: {args.base}",
                        f"Terms: heater to T2 {result.flange.fit.count}, heater to T5 {result.stage.fit.count} "
                        "(chosen by BIC)"]
                       + [f"Residual rms / noise, {path}: T2 {f:.3f}, T5 {s:.3f}"
                          for path, (f, s) in zip(record_paths, result.residual_rms_in_noise)])
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        save_model(model, out, header=header)
    except OSError as error:
        print(f"{PROGRAM}: cannot write {out}: {error}", file=sys.stderr)
        return 2
    warnings = []
    for path, (flange, stage) in zip(record_paths, result.residual_rms_in_noise):
        if flange > 2.0 or stage > 2.0:
            warnings.append(f"the identified model leaves {flange:.3g} x the noise on T2 and {stage:.3g} x on T5 in "
                            f"{path}: these records are not all explained by the model's form (different "
                            "cryostats, or an effect: run cryod analyze on them)")
    for warning in warnings:
        print(f"{PROGRAM}: warning: {warning}", file=sys.stderr)
    text = summary(result, out)
    if report_files is not None:
        with listed_when_written(report_files):
            text["report"] = str(_write_report(args, result, report_files.directory, out, record_paths, acquisition,
                                               config, warnings))
    if args.json:
        print(json.dumps(text))
    else:
        for key in ("model", "heater_to_thermometer_terms", "heater_to_thermometer_time_constants_s",
                    "heater_to_thermometer_dc_gain_K_per_W", "heater_to_ptc_stage_terms",
                    "heater_to_ptc_stage_gain_K_per_W", "heater_to_ptc_stage_time_constant_s",
                    "ptc_line_gain_T2_over_T5", "ptc_line_T2_lag_behind_T5_rad", "noise_rms_K", "report"):
            if key in text:
                print(f"{key}: {text[key]}")
        for name, item in text["parameters"].items():
            print(f"  {name}: {item['value']:.6g} +- {item['standard_uncertainty']:.2g}")
    return 0


def _run_series(args, config, base, out: Path) -> int:
    """``--acquire --setpoints``: the experiment about each setpoint in turn and its model, into the folder ``out``."""
    from cryod.identification.setpoint_series import identify_at_setpoint, model_file_name, plans_at

    if not args.acquire:
        print(f"{PROGRAM}: --setpoints runs the experiment about each setpoint: it needs --acquire", file=sys.stderr)
        return 2
    try:
        plans = plans_at(args.setpoints, _plan(args))
    except ValueError as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    top = config.control.setpoint_max_K
    outside = [plan.setpoint_K for plan in plans if not config.control.setpoint_min_K <= plan.setpoint_K <= top]
    if outside:
        print(f"{PROGRAM}: --setpoints {', '.join(map(str, outside))} K outside control.setpoint_min_K.."
              f"setpoint_max_K = {config.control.setpoint_min_K:g}..{top:g} K of {config.source}", file=sys.stderr)
        return 2
    targets = [out / model_file_name(plan.setpoint_K) for plan in plans]
    for target in targets:
        refusal = output_file_refusal(PROGRAM, target, force=args.force, inputs=[Path(args.base)])
        if refusal is not None:
            print(f"{PROGRAM}: {refusal}", file=sys.stderr)
            return 2
    written = []
    for plan, target in zip(plans, targets):
        print(f"{PROGRAM}: about {plan.setpoint_K:g} K ({len(written) + 1} of {len(plans)})", file=sys.stderr)
        status, acquisition = _acquire(args, config, base, plan)
        if status != 0:
            return status
        try:
            records = [read_record_data(path) for path in acquisition.record_paths]
            result = identify_at_setpoint(plan.setpoint_K, records, acquisition.record_paths, base, plan.line_hold_s,
                                          harmonics=not args.no_harmonics, max_terms=args.max_terms,
                                          replicates=args.bootstrap)
        except (RecordFormatError, FileFormatError, IdentificationError, ValueError, ArithmeticError) as error:
            print(f"{PROGRAM}: about {plan.setpoint_K:g} K: {error}; the records are kept: "
                  f"{' '.join(map(str, acquisition.record_paths))}", file=sys.stderr)
            return 1
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            save_model(result.model, target, header=f"Written by cryod identify --acquire --setpoints: about "
                                                    f"{plan.setpoint_K:g} K, from "
                                                    f"{', '.join(map(str, acquisition.record_paths))}\n"
                                                    f"Base model: {args.base}")
        except OSError as error:
            print(f"{PROGRAM}: cannot write {target}: {error}", file=sys.stderr)
            return 2
        model = result.model
        written.append({"setpoint_K": plan.setpoint_K, "model": str(target),
                        "records": [str(path) for path in acquisition.record_paths],
                        "heater_to_thermometer_dc_gain_K_per_W": model.heater_to_thermometer.dc_gain,
                        "heater_to_thermometer_time_constants_s": model.heater_to_thermometer.time_constants_s,
                        "residual_rms_in_noise": result.identification.residual_rms_in_noise})
        print(f"{PROGRAM}: {target}: heater to T2 {model.heater_to_thermometer.dc_gain:.4g} K/W, time constants "
              f"{', '.join(f'{tau:.4g}' for tau in model.heater_to_thermometer.time_constants_s)} s", file=sys.stderr)
    zones = " ".join(f"{item['setpoint_K']:g}={item['model']}" for item in written)
    print(f"{PROGRAM}: next, the zones' gains: cryod tune --zones {zones} --zones-out zones.yaml", file=sys.stderr)
    if args.json:
        print(json.dumps(plain({"setpoints": written})))
    return 0


def _report_files(args, directory: Path, record_count: int, inputs: list[Path]) -> OutputFiles:
    """The files the report writes into ``directory``, for ``record_count`` records."""
    from cryod.identification.report import REPORT_NAME

    names = [REPORT_NAME]
    if not args.no_figures:
        from cryod.identification.figures import figure_files

        names += figure_files(record_count).values()
    return OutputFiles(PROGRAM, directory, names, inputs=inputs, what="report")


def _write_report(args, result: ModelIdentification, directory: Path, out: Path, record_paths, acquisition, config,
                  warnings) -> Path:
    from cryod.identification.report import feedforward_section, write_report

    directory.mkdir(parents=True, exist_ok=True)
    figures = {}
    if not args.no_figures:
        from cryod.identification.figures import make_figures

        figures = make_figures(result, directory)
    setpoint = args.setpoint if args.setpoint is not None else config.control.setpoint_K
    feedforward = tuning = None
    if setpoint is not None:
        feedforward = feedforward_section(result.model, setpoint, config.heater.resistance_ohm,
                                          config.heater.max_current_A, config.loop.period_s)
        if not args.no_tune:
            if not args.json:
                print(f"{PROGRAM}: searching PI gains on the identified model (cryod tune) ...", file=sys.stderr)
            tuning = _tuning_text(result.model, setpoint, config)
    return write_report(result, directory, model_path=out, record_paths=record_paths, figures=figures,
                        acquisition=acquisition, feedforward=feedforward, tuning_text=tuning, warnings=warnings)
