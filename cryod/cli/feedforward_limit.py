"""``cryod feedforward-limit [--setpoint K] [--heater-ohm R] [--max-current A] [--model M] ...``.

Prints the physical limit of the cooler-locked feedforward (:mod:`cryod.control.feedforward.limit`)
for one setpoint and heater, and how it changes with the setpoint, the heater resistance and the
current limit: a table for a user choosing a heater before buying one. Defaults come from the
example configuration (heater, setpoint, loop period) and the shipped model.

``--setpoints K,K,...`` gives the limit across a range instead, each setpoint with the model that holds
there: a temperature-dependent model's linear model about it, or with ``--zones TABLE`` the feedforward's
model of the zone holding it (:func:`cryod.control.zone_commissioning.limits_across_range`). A
temperature-dependent model at one setpoint is taken about that setpoint too.

Exit status: 0 done; 2 unusable input (a bad number, a setpoint the heater cannot hold, a model
or configuration file that cannot be read).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import textwrap
from pathlib import Path

from cryod.argument_types import not_negative, number, positive, setpoint_list
from cryod.cli.lab_inputs import InputsNotUsable, add_heater_arguments, lab_inputs
from cryod.config import EXAMPLE_CONFIG_PATH
from cryod.control.feedforward.limit import (
    DEFAULT_AVERAGING_TIME_S,
    MEASURES,
    REPORTED_HARMONICS,
    SWEEP_MAX_CURRENTS_A,
    SWEEP_RESISTANCES_OHM,
    SWEEP_SETPOINTS_K,
    FeedforwardLimit,
    FeedforwardLimitError,
    LimitChange,
    SweepPoint,
    feedforward_limit,
    limit_changes,
    limit_sweep,
)
from cryod.control.feedforward.limit_binding import LimitBinding, limit_binding
from cryod.control.feedforward.limit_range import LimitRange, limit_range
from cryod.control.zone_commissioning import limits_across_range, model_at_temperature, model_of_zone
from cryod.control.zones import zone_table_from
from cryod.model import DEFAULT_MODEL_PATH, linearised_at
from cryod.yaml_source import FileFormatError, Section

PROGRAM = "cryod feedforward-limit"


def configure_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Arguments of ``cryod feedforward-limit``."""
    parser.description = (
        "The least PTC-synchronous oscillation (harmonics 1-6 of T2) that any heater waveform locked to the "
        "cooler can leave, given the heater's bounds (0 to R*I_max^2), the mean power that holds the setpoint "
        "and the loop's hold; what limits it, and how it changes with setpoint, heater resistance and current "
        "limit. Defaults: the example configuration's heater, setpoint and loop period, and the shipped model.")
    parser.add_argument("--setpoint", type=number, default=None, metavar="K",
                        help="flange setpoint in K (default: the configuration's)")
    add_heater_arguments(parser)
    parser.add_argument("--model", default=str(DEFAULT_MODEL_PATH), metavar="M",
                        help="cryostat model file (default: the shipped model)")
    parser.add_argument("--period", type=positive, default=None, metavar="S",
                        help="loop period in s: the heater is held this long (default: the configuration's)")
    parser.add_argument("--heater-delay", type=not_negative, default=0.0, metavar="S",
                        help="delay from a reading to the heater change, s (default 0; the model's dead time "
                             "is added)")
    parser.add_argument("--averaging-time", type=positive, default=DEFAULT_AVERAGING_TIME_S, metavar="S",
                        help=f"averaging time of the line's estimate for the noise floor, s "
                             f"(default {DEFAULT_AVERAGING_TIME_S:g})")
    parser.add_argument("--measure", choices=MEASURES, default="sampled",
                        help="harmonics of the readings at the loop's instants, as the daemon measures (default), "
                             "or of the thermometer's continuous temperature")
    parser.add_argument("--setpoints", type=setpoint_list, default=None, metavar="K,K,...",
                        help="the limit at each of these setpoints, with the model that holds there (a "
                             "temperature-dependent --model's, or --zones' models)")
    parser.add_argument("--zones", type=Path, default=None, metavar="TABLE",
                        help="with --setpoints: a zone table (cryod tune --zones): each setpoint with its zone's "
                             "feedforward model, --model where the zone has none")
    parser.add_argument("--config", default=str(EXAMPLE_CONFIG_PATH), metavar="PATH",
                        help="configuration giving the defaults (default: the example config/cryod.yaml)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    return parser


def run(args: argparse.Namespace) -> int:
    """Compute and print the limit; returns the exit status."""
    try:
        inputs = lab_inputs(args)
    except InputsNotUsable as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    if getattr(args, "setpoints", None) is not None or getattr(args, "zones", None) is not None:
        return run_range(args, inputs)
    config, model, setpoint = inputs.config, inputs.model, inputs.setpoint_K
    if model.temperature_dependence is not None:
        try:
            model = linearised_at(model, setpoint)
        except ValueError as error:
            print(f"{PROGRAM}: {args.model} at {setpoint:g} K: {error}", file=sys.stderr)
            return 2
    resistance, current = inputs.heater_ohm, inputs.max_current_A
    period = args.period if args.period is not None else config.loop.period_s
    options = {"period_s": period, "heater_delay_s": args.heater_delay, "measure": args.measure,
               "averaging_time_s": args.averaging_time}
    try:
        limit = feedforward_limit(model, setpoint, resistance, current, **options)
    except FeedforwardLimitError as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    spread = limit_range(model, setpoint, resistance, current, period, heater_delay_s=args.heater_delay,
                         measure=args.measure, averaging_time_s=args.averaging_time)
    held = {"setpoint_K": setpoint, "heater_resistance_ohm": resistance, "max_current_A": current}
    sweeps = {
        "setpoint": limit_sweep(model, "setpoint", SWEEP_SETPOINTS_K, **held, **options),
        "heater_resistance": limit_sweep(model, "heater_resistance", SWEEP_RESISTANCES_OHM, **held, **options),
        "max_current": limit_sweep(model, "max_current", SWEEP_MAX_CURRENTS_A, **held, **options),
    }
    binding = limit_binding(limit, limit_changes(model, setpoint, limit.max_heater_power_W, **options))
    if args.json:
        summary = limit.summary()
        summary["model"] = str(args.model)
        summary["ptc_periodic_limit_range"] = spread.summary() if spread is not None else None
        summary["sweeps"] = {name: [_sweep_row(row, row_binding(model, row, **options)) for row in rows]
                             for name, rows in sweeps.items()}
        summary["binding"] = binding.summary()
        print(json.dumps(summary))
    else:
        bindings = {name: [row_binding(model, row, **options) for row in rows] for name, rows in sweeps.items()}
        print(report(limit, sweeps, model_path=str(args.model), spread=spread, binding=binding, bindings=bindings))
    return 0


def run_range(args: argparse.Namespace, inputs) -> int:
    """``--setpoints``: the limit at each setpoint with the model that holds there; returns the exit status."""
    if args.setpoints is None:
        print(f"{PROGRAM}: --zones gives the models of a range: give the range with --setpoints", file=sys.stderr)
        return 2
    config, model = inputs.config, inputs.model
    resistance, current = inputs.heater_ohm, inputs.max_current_A
    if args.zones is not None:
        try:
            table = zone_table_file(args.zones, resistance * current ** 2)
        except FileFormatError as error:
            print(f"{PROGRAM}: {error}", file=sys.stderr)
            return 2
        if model.temperature_dependence is not None:
            print(f"{PROGRAM}: --model {args.model} is a temperature-dependent cryostat: with --zones give the "
                  f"controller's model for zones without one (default: the shipped model)", file=sys.stderr)
            return 2
        model_at, source = model_of_zone(table, model), f"the zones of {args.zones}"
    else:
        model_at, source = model_at_temperature(model), str(args.model)
    period = args.period if args.period is not None else config.loop.period_s
    rows = limits_across_range(args.setpoints, model_at, resistance, current, period,
                               heater_delay_s=args.heater_delay, measure=args.measure,
                               averaging_time_s=args.averaging_time)
    if args.json:
        print(json.dumps({"models": source, "heater_resistance_ohm": resistance, "max_current_A": current,
                          "period_s": period, "setpoints": [row.to_dict() for row in rows]}))
        return 0
    print(f"the feedforward's limit with {resistance:g} ohm at up to {current * 1e3:g} mA "
          f"({resistance * current ** 2:.4g} W), models: {source}")
    print("setpoint   model                                 mean heater   open line    limit        reachable    authority  "
          "limited by")
    for row in rows:
        if row.problem:
            print(f"{row.setpoint_K:8g} K  {row.model_name[:36]:36s}  {row.problem}")
            continue
        print(f"{row.setpoint_K:8g} K  {row.model_name[:36]:36s}  {_mw(row.mean_heater_power_W):>11s}  "
              f"{_mk(row.open_line_K):>11s}  {_mk(row.ptc_periodic_limit_K):>11s}  "
              f"{_mk(row.predicted_best_residual_K):>11s}  {row.authority:9.3g}  {row.limited_by}")
    return 0


def zone_table_file(path: Path, heater_max_power_w: float):
    """The zone table in a file holding ``zones:`` (as ``cryod tune --zones`` writes it), checked."""
    holder = Section.from_file(path)
    table = zone_table_from(holder, 0.0, 0.0, heater_max_power_w)
    holder.finish()
    return table


def row_binding(model, row: SweepPoint, period_s: float, **options) -> LimitBinding | None:
    """What binds one row's limit: a top its waveform touches is checked against a heater twice as large."""
    limit = row.limit
    if limit is None:
        return None
    changes: tuple[LimitChange, ...] = ()
    if limit_binding(limit).bound == "floor and top":
        changes = limit_changes(model, limit.setpoint_K, limit.max_heater_power_W, period_s, **options)[2:]
    return limit_binding(limit, changes)


def _sweep_row(row: SweepPoint, binding: LimitBinding | None) -> dict:
    summary = {"value": row.value, "mean_heater_power_W": row.mean_heater_power_W,
               "max_heater_power_W": row.max_heater_power_W}
    if row.limit is None:
        return {**summary, "problem": row.problem}
    limit = row.limit
    assert binding is not None              # a row with a limit has what binds it (row_binding)
    return {**summary, "authority": limit.authority, "best_sinusoid_K": limit.best_sinusoid_K,
            "ptc_periodic_limit_K": limit.ptc_periodic_limit_K, "limited_by": limit.limited_by,
            "bound": binding.bound}


#: What binds, as the table says it.
_BOUND_WORDS = {"floor": "the 0 W floor", "top": "the top R I_max^2", "floor and top": "the 0 W floor and the top",
                "none": "noise (no bound binds)"}


def _mk(value_K: float) -> str:
    return f"{value_K * 1e3:.3f} mK"


def _mw(value_w: float) -> str:
    return f"{value_w * 1e3:.1f} mW"


def report(limit: FeedforwardLimit, sweeps: dict, model_path: str = "", spread: LimitRange | None = None,
           binding: LimitBinding | None = None, bindings: dict | None = None) -> str:
    """The table printed by the command (with the limit's range over the model's uncertainty when it states one,
    and what binds it and each row of the sweeps, ``bindings``: a list per sweep, as ``sweeps``)."""
    binding = binding or limit_binding(limit)
    ratio = limit.open_line_K / limit.ptc_periodic_limit_K if limit.ptc_periodic_limit_K > 0 else math.inf
    lines = [
        f"Physical limit of the cooler-locked feedforward ({limit.measure} measure: harmonics 1-{REPORTED_HARMONICS} "
        f"of T2, sqrt(2) x rms)",
        f"  model                         {model_path}",
        f"  setpoint                      {limit.setpoint_K:g} K",
        f"  heater                        {limit.heater_resistance_ohm:g} ohm, {limit.max_current_A:g} A: "
        f"0 to {_mw(limit.max_heater_power_W)}",
        f"  loop period, heater delay     {limit.period_s * 1e3:g} ms, {limit.heater_delay_s * 1e3:g} ms",
        f"  mean heater power (balance)   {_mw(limit.mean_heater_power_W)}",
        f"  heater to T2 at the line      {limit.thermometer_gain_at_line_K_per_W * 1e3:.2f} mK/W, "
        f"{limit.thermometer_phase_at_line_deg:.0f} deg; through the {limit.period_s * 1e3:g} ms hold "
        f"{limit.heater_gain_at_line_K_per_W * 1e3:.2f} mK/W, {limit.heater_phase_at_line_deg:.0f} deg",
        f"  line power needed             {_mw(limit.line_power_needed_W)} (cancels the line's fundamental)",
        f"  largest line power possible   {_mw(limit.largest_line_power_W)} (a rectangular pulse); "
        f"a sinusoid: {_mw(limit.sinusoid_line_power_W)}",
        f"  authority                     {limit.authority:.2f} (largest / needed)",
        f"  open line (no feedforward)    {_mk(limit.open_line_K)}",
        f"  best sinusoid                 {_mk(limit.best_sinusoid_K)}",
        f"  limit (best waveform)         {_mk(limit.ptc_periodic_limit_K)}"
        + (f"  ({ratio:.1f}x below the open line)" if math.isfinite(ratio) else "  (the line can be cancelled)"),
        "  limit, model's uncertainty    " + (spread.describe() if spread is not None else
                                            "not stated (the model file has no uncertainty section)"),
        "  limit per harmonic 1-6        " + "  ".join(f"{v * 1e3:.3f}" for v in limit.limit_harmonics_K) + " mK",
        f"  whole waveform, harmonics 1-{limit.harmonics:<2d} {_mk(limit.whole_periodic_limit_K)}"
        + (f"; no waveform of any shape goes below {_mk(limit.lower_bound_K)}" if limit.lower_bound_K is not None
           else ""),
        f"  noise floor ({limit.averaging_time_s:g} s averaging)   {limit.noise_floor_K * 1e6:.1f} µK",
        f"  predicted best residual       {_mk(limit.predicted_best_residual_K)}",
        f"  limited by                    {limit.limited_by}: {_BOUND_WORDS[binding.bound]}",
        "",
        *textwrap.wrap("What binds: " + binding.explanation, 110, initial_indent="", subsequent_indent="  "),
        "",
        "What would change it (mean power / max power / authority / best sinusoid / limit / what binds):",
        "  (0 W floor: a bigger heater does not help, a higher setpoint does; top R I_max^2: a bigger heater helps)",
    ]
    titles = {"setpoint": ("setpoint", "K"), "heater_resistance": ("heater resistance", "ohm"),
              "max_current": ("current limit", "A")}
    for name, rows in sweeps.items():
        title, unit = titles[name]
        lines.append(f"  {title}:")
        row_bindings = (bindings or {}).get(name) or [limit_binding(row.limit) if row.limit else None for row in rows]
        for row, row_bound in zip(rows, row_bindings):
            start = f"    {f'{row.value:g} {unit}':>10}  {_mw(row.mean_heater_power_W):>9} {_mw(row.max_heater_power_W):>10}"
            if row.limit is None:
                reason = "the heater cannot cool" if row.mean_heater_power_W < 0.0 else "more than the heater gives"
                lines.append(f"{start}  out of reach: {reason}")
                continue
            item = row.limit
            lines.append(f"{start}  {item.authority:5.2f}  {_mk(item.best_sinusoid_K):>10}"
                         f"  {_mk(item.ptc_periodic_limit_K):>10}  {_BOUND_WORDS[row_bound.bound]}")
    return "\n".join(lines)
