"""``cryod tune [--model M] [--setpoint K] [--heater-ohm R] [--max-current A] [--config PATH] [--json]``,
and ``cryod tune --zones K=MODEL [K=MODEL ...] [--zones-out PATH]``: a zone table.

Suggests PI gains for a setpoint step on the lab's model and heater (:mod:`cryod.control.tuning`), and
shows beside them how the configuration's gains and the paper's (Kp 80 W/K, Ki 4 W/(K s)) do on the
same step: rise, overshoot, settling to 1 mK, offset, the cooler line under PI, the heater at its
bounds, the loop's margins. It takes about half a minute (some 70 steps on the model).

With ``--zones``, one identified model per setpoint (``cryod identify --acquire --setpoints``), it
suggests each zone's gains on its own model for the move into it, from the previous setpoint at the
configuration's ramp (:mod:`cryod.control.zone_commissioning`), and writes the zone table
(``control.zones``) with each zone's model as its feedforward's.

Exit status: 0 done; 2 unusable input (a bad number, a model or configuration that cannot be read,
a step the heater cannot make, no gains meeting the tolerances).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from cryod.argument_types import not_negative, number, positive
from cryod.cli.lab_inputs import InputsNotUsable, add_heater_arguments, lab_inputs
from cryod.config import EXAMPLE_CONFIG_PATH
from cryod.control.pi import PiGains
from cryod.control.tuning import StepPerformance, Tolerances, TuningError, step_performance, suggest_gains
from cryod.model import DEFAULT_MODEL_PATH

PROGRAM = "cryod tune"
#: The paper's gains, in the units docs/explanation/control.md argues for.
PAPER_GAINS = PiGains(80.0, 4.0)


def configure_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Arguments of ``cryod tune``."""
    parser.description = (
        "PI gains that settle a setpoint step fastest on the model with the lab's heater, keeping the "
        "overshoot, the offset, the cooler line under PI, the heater's bounds and the loop's stability "
        "margins within tolerances; and the same step with the configuration's gains and the paper's "
        "(Kp 80 W/K, Ki 4 W/(K s)). Defaults: the configuration's setpoint and heater, the shipped model.")
    parser.add_argument("--model", default=str(DEFAULT_MODEL_PATH), metavar="M",
                        help="cryostat model file (default: the shipped model; use the lab's, from cryod identify)")
    parser.add_argument("--setpoint", type=number, default=None, metavar="K",
                        help="the step's target in K (default: the configuration's setpoint)")
    parser.add_argument("--from-power", type=not_negative, default=0.0, metavar="W",
                        help="heater power the cryostat has settled at before the step (default 0: the model's "
                             "operating point)")
    add_heater_arguments(parser)
    parser.add_argument("--duration", type=positive, default=None, metavar="S",
                        help="length of each step in s (default 900; with --zones the ramp's time plus two of "
                             "the zone model's longest time constants, at least 900; the last 200 s judge the "
                             "settled state)")
    parser.add_argument("--zones", nargs="+", type=_zone_model, default=None, metavar="K=MODEL",
                        help="one identified model per setpoint (cryod identify --acquire --setpoints): a zone "
                             "each, its gains suggested on its model for the move from the previous setpoint")
    parser.add_argument("--zones-out", type=Path, default=None, metavar="PATH",
                        help="with --zones: write the zone table here (default: print it), to name as "
                             "control.zones: PATH or to paste under control:")
    parser.add_argument("--force", action="store_true", help="overwrite --zones-out if it exists")
    parser.add_argument("--max-overshoot", type=not_negative, default=1.0, metavar="MK",
                        help="largest acceptable overshoot of the cooler-period average, mK (default 1)")
    parser.add_argument("--max-line-ratio", type=positive, default=Tolerances.line_ratio, metavar="X",
                        help=f"largest acceptable cooler line under PI against the open line (default "
                             f"{Tolerances.line_ratio:g}; with the feedforward on, PI does not see the line)")
    parser.add_argument("--min-phase-margin", type=not_negative, default=45.0, metavar="DEG",
                        help="smallest acceptable phase margin of the loop, degrees (default 45)")
    parser.add_argument("--config", default=str(EXAMPLE_CONFIG_PATH), metavar="PATH",
                        help="configuration giving the defaults and the gains to compare (default: the example "
                             "config/cryod.yaml)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    return parser


def _zone_model(text: str) -> tuple[float, str]:
    """``K=MODEL``: a setpoint and the model identified about it."""
    setpoint, separator, path = text.partition("=")
    try:
        value = number(setpoint)
    except argparse.ArgumentTypeError:
        value = None
    if not separator or not path or value is None or not value > 0.0:
        raise argparse.ArgumentTypeError(f"give SETPOINT_K=MODEL_FILE, e.g. 12=model-12K.yaml; got {text!r}")
    return value, path


def run(args: argparse.Namespace) -> int:
    """Search, compare and print; returns the exit status."""
    if getattr(args, "zones", None) is not None:
        return run_zones(args)
    args.duration = args.duration if args.duration is not None else 900.0
    try:
        inputs = lab_inputs(args)
    except InputsNotUsable as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    config, model, setpoint = inputs.config, inputs.model, inputs.setpoint_K
    resistance, current = inputs.heater_ohm, inputs.max_current_A
    heater_max_w = resistance * current ** 2
    tolerances = Tolerances(overshoot_K=args.max_overshoot * 1e-3, phase_margin_deg=args.min_phase_margin,
                            line_ratio=args.max_line_ratio)
    options = {"start_heater_w": args.from_power, "duration_s": args.duration, "period_s": config.loop.period_s}
    if args.from_power > heater_max_w:
        print(f"{PROGRAM}: --from-power {args.from_power:g} W is above R I_max^2 = {heater_max_w:g} W", file=sys.stderr)
        return 2
    try:
        if not args.json:
            print(f"searching Kp and Ki on {args.model} ({resistance:g} ohm, {current * 1e3:g} mA: "
                  f"{heater_max_w * 1e3:.0f} mW), step to {setpoint:g} K ...", file=sys.stderr)
        tuning = suggest_gains(model, setpoint, heater_max_w, tolerances=tolerances, **options)
        configured = step_performance(model, config.control.term("pi"), setpoint, heater_max_w, **options)
        paper = step_performance(model, PAPER_GAINS, setpoint, heater_max_w, **options)
    except TuningError as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    rows = (("suggested", tuning.best), (f"configuration ({args.config})", configured),
            ("paper (Kp 80, I 4 as W/K, W/(K s))", paper))
    if args.json:
        print(json.dumps({
            "model": str(args.model), "setpoint_K": setpoint, "heater_resistance_ohm": resistance,
            "max_current_A": current, "start_K": tuning.best.start_K, "runs": len(tuning.runs),
            "tolerances": {"overshoot_mK": tolerances.overshoot_K * 1e3, "offset_mK": tolerances.offset_K * 1e3,
                           "line_over_open": tolerances.line_ratio,
                           "heater_at_bounds_percent": 100 * tolerances.at_bounds_fraction,
                           "phase_margin_deg": tolerances.phase_margin_deg, "gain_margin": tolerances.gain_margin},
            "suggested": tuning.best.summary(), "configured": configured.summary(), "paper": paper.summary(),
            "configured_meets_tolerances": not tolerances.violations(configured),
            "paper_meets_tolerances": not tolerances.violations(paper)}))
    else:
        print(report(rows, tolerances, tuning.best.start_K, setpoint))
    return 0


def run_zones(args: argparse.Namespace) -> int:
    """``--zones``: each zone's gains on its model, the zone table written or printed; returns the exit status."""
    from cryod.config import load_config
    from cryod.control.zone_commissioning import tune_zones, zone_table, zone_table_text
    from cryod.model import load_model
    from cryod.output_files import output_file_refusal
    from cryod.yaml_source import FileFormatError

    try:
        config = load_config(args.config)
        zone_models = []
        for setpoint, path in sorted(args.zones):
            model = load_model(path)
            if model.temperature_dependence is not None:
                raise FileFormatError(path, None, "temperature_dependence", "a temperature-dependent cryostat, not "
                                      "a zone's model: give the models cryod identify --acquire --setpoints wrote")
            where = args.zones_out.parent if args.zones_out is not None else Path.cwd()
            zone_models.append((setpoint, model, os.path.relpath(Path(path).resolve(), where.resolve())))
    except (FileFormatError, OSError) as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    if args.zones_out is not None:
        refusal = output_file_refusal(PROGRAM, args.zones_out, force=args.force,
                                      inputs=[Path(path) for _, path in args.zones] + [Path(args.config)])
        if refusal is not None:
            print(f"{PROGRAM}: {refusal}", file=sys.stderr)
            return 2
    resistance = args.heater_ohm if args.heater_ohm is not None else config.heater.resistance_ohm
    current = args.max_current if args.max_current is not None else config.heater.max_current_A
    heater_max_w = resistance * current ** 2
    ramp = config.control.ramp_K_per_min
    tolerances = Tolerances(overshoot_K=args.max_overshoot * 1e-3, phase_margin_deg=args.min_phase_margin,
                            line_ratio=args.max_line_ratio)
    setpoints = [setpoint for setpoint, _, _ in zone_models]

    def duration(model) -> float:
        if args.duration is not None:
            return args.duration
        index = next(i for i, (_, zone_model, _) in enumerate(zone_models) if zone_model is model)
        start = setpoints[index - 1] if index else model.operating_point.flange_temperature_K
        ramp_s = abs(setpoints[index] - start) / ramp * 60.0 if ramp > 0.0 else 0.0
        return max(900.0, ramp_s + 2.0 * max(model.heater_to_thermometer.time_constants_s, default=0.0))

    if not args.json:
        print(f"tuning {len(zone_models)} zones ({resistance:g} ohm, {current * 1e3:g} mA, ramp {ramp:g} K/min) ...",
              file=sys.stderr)
    try:
        tunings = tune_zones(zone_models, heater_max_w, setpoint_max_K=config.control.setpoint_max_K,
                             ramp_K_per_min=ramp, tolerances=tolerances, duration_s=duration,
                             period_s=config.loop.period_s,
                             progress=None if args.json else lambda line: print(line, file=sys.stderr))
    except TuningError as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    header = (f"Zone table written by cryod tune --zones ({resistance:g} ohm, {current * 1e3:g} mA, ramp {ramp:g} "
              f"K/min, configuration {args.config}):\nname it as control.zones: FILE, or paste it under control:")
    text = zone_table_text(zone_table(tunings), header)
    if args.zones_out is not None:
        try:
            args.zones_out.write_text(text, encoding="utf-8")
        except OSError as error:
            print(f"{PROGRAM}: cannot write {args.zones_out}: {error}", file=sys.stderr)
            return 2
    if args.json:
        print(json.dumps({"zones": [{"setpoint_K": item.setpoint_K, "upper_K": item.upper_K, "start_K": item.start_K,
                                     "model": item.model_source, **item.tuning.best.summary()} for item in tunings],
                          "table": str(args.zones_out) if args.zones_out is not None else text}))
    elif args.zones_out is None:
        print(text, end="")
    else:
        print(f"zone table written to {args.zones_out}", file=sys.stderr)
    return 0


def report(rows, tolerances: Tolerances, start_K: float, setpoint_K: float) -> str:
    """The comparison table in markdown, with what each row breaks."""
    lines = [f"Step {start_K:.4f} K -> {setpoint_K:g} K on the model; T2 averaged over whole cooler periods for "
             "overshoot and settling; the settled state over the last 200 s.", "",
             "| gains | Kp (W/K) | Ki (W/(K s)) | rise (s) | overshoot (mK) | within 1 mK after (s) | offset (mK) "
             "| cooler line (mK, x open) | heater at bounds | phase margin | gain margin |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    notes = []
    for name, step in rows:
        lines.append(_row(name, step))
        broken = tolerances.violations(step)
        if broken:
            notes.append(f"- {name}: {'; '.join(broken)}")
    lines += ["", "Tolerances: overshoot {:g} mK, offset {:g} mK, line {:g}x open, heater at bounds {:g} % of the "
              "time, phase margin {:g} deg, gain margin {:g}.".format(
                  tolerances.overshoot_K * 1e3, tolerances.offset_K * 1e3, tolerances.line_ratio,
                  100 * tolerances.at_bounds_fraction, tolerances.phase_margin_deg, tolerances.gain_margin)]
    if notes:
        lines += ["", "Outside the tolerances:", *notes]
    lines += ["", "To use the suggestion: control.pi.proportional_W_per_K and integral_W_per_K_s in the "
              "configuration, then `systemctl reload cryod` (bumpless)."]
    return "\n".join(lines)


def _row(name: str, step: StepPerformance) -> str:
    def seconds(value: float) -> str:
        return f"{value:.0f}" if value < float("inf") else "never"
    return (f"| {name} | {step.gains.proportional_w_per_K:.3g} | {step.gains.integral_w_per_K_s:.3g} | "
            f"{seconds(step.rise_s)} | {step.overshoot_K * 1e3:.2f} | {seconds(step.settle_s)} | "
            f"{step.offset_K * 1e3:+.3f} | {step.line_K * 1e3:.3f} ({step.line_ratio:.3f}) | "
            f"{100 * step.at_bounds_fraction:.0f} % | {step.phase_margin_deg:.0f} deg | {step.gain_margin:.1f} |")
