"""Zones from 5 K to 24 K on the temperature-dependent cryostat: commissioned zones against one set of gains.

Run: PYTHONPATH=. python3 benchmarks/zones.py commission    (identify at each setpoint, tune each zone:
                                                             writes config/zones-4-25K.yaml and its models)
     PYTHONPATH=. python3 benchmarks/zones.py run [--json OUT]
     PYTHONPATH=. python3 benchmarks/zones.py hold [--setpoint 24] [--seeds 3,4] [--hold 4800]
                                                   [--feedforward-model zone|linearised|FILE]

Both on the simulated cryostat of config/model-4-25K.yaml, with the daemon's own code path (drivers,
simulated instruments in process, the loop, the data log) on virtual time, the configuration
config/cryod-4-25K.yaml (1000 ohm, 100 mA, ramp 0.1 K/min, feedforward on).

``commission`` runs the two commands a lab runs: ``cryod identify --acquire --simulate --setpoints
5,8,12,16,20,24`` (at each setpoint the experiment about it: regulate, hold, a 50 mK setpoint step; the
fit of its hold and step, one model per setpoint with uncertainties; ``--max-settle 4000``) into
config/zone-models/, then ``cryod tune --zones ... --max-overshoot 2`` (each zone's gains on its own
model for the move into it, from the previous setpoint at the ramp) into config/zones-4-25K.yaml.

``run`` takes the setpoints in turn, each held until 2400 s after its ramp ends, twice: with the
commissioned zones, and with one set of gains (the 5 K zone's, with its model as the feedforward's,
as a lab with one zone commissioned at 5 K would run). For each setpoint: the time from its command,
and from the ramp's end, until T2 averaged over four cooler periods stays within 1 mK; the overshoot
of that average; T2's periodic amplitude (harmonics 1-6 against the cooler's phase from T5) over the
last 300 s against the feedforward's physical limit for the simulated cryostat there (its tangent
model, the heater, the loop's timing; the noise floor of a 300 s estimate included); faults and
overruns over the whole run.

``hold`` takes one setpoint alone (from 4.23 K at the ramp) with the commissioned zones, holds it ``--hold``
seconds after its ramp, once per seed, and judges T2's periodic amplitude in each 300 s window of the hold
and over the hold from 1200 s after the ramp as one window, each against its noise floor: what one window's
noise spreads, and what a longer window resolves. ``--feedforward-model`` gives the last zone, split at
``--split-K``, another feedforward model above the split: ``linearised``, the simulated cryostat's own linear
model at the setpoint.

Results: ``benchmarks/results/zones.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cryod.config import load_config
from cryod.control.pi import PiGains
from cryod.control.feedforward.limit import noise_floor_K
from cryod.control.zone_commissioning import limits_across_range, model_at_temperature
from cryod.control.zones import ZoneTable
from cryod.identification.setpoint_series import model_file_name
from cryod.model import TEMPERATURE_MODEL_PATH, load_model
from cryod.model.temperature_plant import linearised_at
from cryod.records.columns import Row
from cryod.records.metrics import regulation_metrics
from drivers.clock import VirtualClock
from cryod.service.commands import Command
from cryod.service.daemon import Daemon
from cryod.service.simulation import DryRunOptions, SimulatedInstrumentsOpener, simulation_config

REPOSITORY = Path(__file__).resolve().parent.parent
CONFIG = REPOSITORY / "config" / "cryod-4-25K.yaml"
TABLE = REPOSITORY / "config" / "zones-4-25K.yaml"
MODELS = REPOSITORY / "config" / "zone-models"
SETPOINTS_K = (5.0, 8.0, 12.0, 16.0, 20.0, 24.0)
HOLD_AFTER_RAMP_S = 2400.0
WINDOW_S = 300.0
LONG_WINDOW_FROM_S = 1200.0      # hold: the long window starts this long after the ramp's end
BAND_K = 1e-3
AVERAGED_PERIODS = 4


def simulated(config_path: Path, folder: Path, seed: int = 0):
    """The configuration for a run in ``folder`` on virtual time, in process."""
    overrides = DryRunOptions(transport="in-process", speed="max", seed=seed, data_dir=folder / "data",
                              socket=folder / "control.sock")
    return simulation_config(overrides, load_config(config_path))


# -- commissioning -------------------------------------------------------------------------
def cryod(*arguments: str) -> dict:
    """One ``cryod ... --json`` command in a process of its own; its JSON summary."""
    command = [sys.executable, "-m", "cryod.cli", *arguments, "--json"]
    print("$ cryod " + " ".join(arguments), flush=True)
    result = subprocess.run(command, capture_output=True, text=True, cwd=REPOSITORY)
    if result.returncode != 0:
        raise RuntimeError(f"cryod {' '.join(arguments)}: exit {result.returncode}: {result.stderr[-2000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def commission() -> dict:
    """The two commands a lab runs: the models about each setpoint, then the zones' gains and the table."""
    report = {}
    with tempfile.TemporaryDirectory() as scratch:
        started = time.perf_counter()
        report["identify"] = cryod("identify", "--acquire", "--simulate", "--config", str(CONFIG), "--setpoints",
                                   ",".join(f"{value:g}" for value in SETPOINTS_K), "--max-settle", "4000",
                                   "--out", str(MODELS), "--force", "--data-dir", f"{scratch}/data",
                                   "--socket", f"{scratch}/control.sock")
        report["identify_wall_s"] = time.perf_counter() - started
    started = time.perf_counter()
    zones = [f"{value:g}={MODELS / model_file_name(value)}" for value in SETPOINTS_K]
    report["tune"] = cryod("tune", "--config", str(CONFIG), "--zones", *zones, "--zones-out", str(TABLE),
                           "--max-overshoot", "2", "--force")
    report["tune_wall_s"] = time.perf_counter() - started
    return report


# -- the run -----------------------------------------------------------------------------
class SetpointProgram:
    """A row tap: the setpoints in turn, each held until ``hold_after_ramp_s`` after its ramp has ended."""

    def __init__(self, setpoints_K, submit, stop, hold_after_ramp_s: float = HOLD_AFTER_RAMP_S):
        self.setpoints = list(setpoints_K)
        self.hold_after_ramp_s = hold_after_ramp_s
        self.submit, self.stop = submit, stop
        self.index = -1
        self.ramp_end_s = math.inf
        self.times, self.flange, self.stage, self.setpoint, self.heater, self.commanded = [], [], [], [], [], []
        self.wall, self._last_wall = [], None      # wall time from one row to the next (s): a tick's cost

    def __call__(self, item) -> None:
        if type(item) is not Row or item.state is None or str(item.state) in ("holding", "recovering"):
            return
        time_s = float(item.time_s)
        now = time.perf_counter()
        self.wall.append(now - self._last_wall if self._last_wall is not None else math.nan)
        self._last_wall = now
        self.times.append(time_s)
        self.flange.append(float(item.T2_K))
        self.stage.append(float(item.T5_K))
        self.setpoint.append(float(item.setpoint_K) if item.setpoint_K is not None else math.nan)
        self.heater.append(float(item.heater_W))
        target = self.setpoints[self.index] if self.index >= 0 else None
        if target is not None and math.isinf(self.ramp_end_s) and self.setpoint[-1] == target:
            self.ramp_end_s = time_s
        if self.index < 0 or time_s >= self.ramp_end_s + self.hold_after_ramp_s:
            self.index += 1
            if self.index >= len(self.setpoints):
                self.stop("the program's last setpoint held")
                return
            self.ramp_end_s = math.inf
            self.commanded.append(time_s)
            self.submit(self.setpoints[self.index])


def run_once(config_path: Path, zones: bool, gains: PiGains | None, ff_model, seed: int = 3,
             setpoints_K=SETPOINTS_K, hold_after_ramp_s: float = HOLD_AFTER_RAMP_S, top_zone=None,
             windows: bool = False) -> dict:
    """One run of the program; ``top_zone`` (lower K, model, source): the last zone split there, the part above
    with that feedforward model and the same gains; ``windows``: each setpoint's hold judged in consecutive
    windows too (:func:`hold_windows`)."""
    truth = load_model(TEMPERATURE_MODEL_PATH)
    with tempfile.TemporaryDirectory() as scratch:
        config = simulated(config_path, Path(scratch), seed)
        control = config.control
        if zones and top_zone is not None:
            lower_K, model, source = top_zone
            last = control.zones.zones[-1]
            split = (dataclasses.replace(last, upper_K=lower_K),
                     dataclasses.replace(last, feedforward_model=model, feedforward_model_source=source))
            control = dataclasses.replace(control, zones=dataclasses.replace(
                control.zones, zones=control.zones.zones[:-1] + split))
            config = dataclasses.replace(config, control=control)
        if not zones:
            terms = tuple((name, gains if name == "pi" else dataclasses.replace(settings, model=ff_model,
                                                                                model_source="5 K zone's model")
                           if name == "feedforward" else settings) for name, settings in control.terms)
            control = dataclasses.replace(control, zones=None, terms=terms)
        config = dataclasses.replace(config, control=dataclasses.replace(control, setpoint_K=None))
        holder = {}
        program = SetpointProgram(setpoints_K, lambda value: holder["daemon"].loop.submit(Command("setpoint", value)),
                                  lambda reason: holder["daemon"].loop.request_stop(reason), hold_after_ramp_s)
        events = []
        daemon = Daemon(config, SimulatedInstrumentsOpener(truth, seed), VirtualClock(),
                        metadata={"simulated": "yes (benchmarks/zones.py)"}, install_signal_handlers=False,
                        row_taps=[program, lambda item: events.append(item) if type(item) is not Row else None])
        holder["daemon"] = daemon
        started = time.perf_counter()
        result = daemon.run()
        wall = time.perf_counter() - started
        timing = result.loop.timing.summary()
        delay = result.loop.regulator.term("feedforward").setting_delay_s
    arrays = {name: np.array(getattr(program, name))
              for name in ("times", "flange", "stage", "setpoint", "heater", "wall")}
    wall_ms = arrays["wall"][np.isfinite(arrays["wall"])] * 1e3
    table_zones = config.control.zones
    crossings = np.flatnonzero(np.diff([table_zones.index_for(value) if np.isfinite(value) else -1
                                        for value in arrays["setpoint"]]) != 0) + 1 if table_zones else np.zeros(0, int)
    limits = limits_across_range(setpoints_K, model_at_temperature(truth), config.heater.resistance_ohm,
                                 config.heater.max_current_A, config.loop.period_s, heater_delay_s=delay,
                                 averaging_time_s=WINDOW_S)
    rows = []
    boundaries = program.commanded + [arrays["times"][-1] + 1.0]
    for index, (setpoint, limit) in enumerate(zip(setpoints_K, limits)):
        rows.append(judge(arrays, setpoint, boundaries[index], boundaries[index + 1], limit,
                          truth.ptc.angular_frequency_rad_s))
        if windows:
            rows[-1]["windows"] = hold_windows(arrays, setpoint, boundaries[index], boundaries[index + 1],
                                               truth.ptc.angular_frequency_rad_s,
                                               truth.sensor_noise.flange_thermometer_rms_K, config.loop.period_s)
    kinds = {}
    for event in events:
        kinds[event.kind] = kinds.get(event.kind, 0) + 1
    return {"zones": zones, "seed": seed, "setpoints": rows,
            "feedforward_events": [event.message for event in events if event.kind.startswith("feedforward")], "exit_code": result.exit_code, "overruns": timing.get("overruns", 0),
            "lateness_ms_max": timing.get("lateness_ms_max"), "faults": kinds.get("fault", 0),
            "zone_events": [event.message for event in events if event.kind == "zone"],
            "simulated_h": float(arrays["times"][-1] - arrays["times"][0]) / 3600.0, "wall_s": wall,
            "tick_wall_ms": {"p50": float(np.percentile(wall_ms, 50)), "p99": float(np.percentile(wall_ms, 99)),
                             "max": float(wall_ms.max()),
                             "zone_changes": [float(arrays["wall"][index] * 1e3) for index in crossings
                                              if index < arrays["wall"].size]}}


def judge(arrays: dict, setpoint_K: float, start_s: float, end_s: float, limit, line_rad_s: float) -> dict:
    part = (arrays["times"] >= start_s) & (arrays["times"] < end_s)
    times, flange = arrays["times"][part], arrays["flange"][part]
    width = max(1, int(round(AVERAGED_PERIODS * 2.0 * math.pi / line_rad_s / 0.08)))
    averaged = np.convolve(flange, np.ones(width) / width, mode="valid")
    averaged_t = times[width // 2:width // 2 + averaged.size]
    ramp_end = times[np.flatnonzero(arrays["setpoint"][part] == setpoint_K)[0]]
    outside = np.flatnonzero(np.abs(averaged - setpoint_K) > BAND_K)
    settled_at = averaged_t[0] if outside.size == 0 else (averaged_t[outside[-1] + 1] if outside[-1] + 1 < averaged.size
                                                          else math.inf)
    direction = 1.0 if setpoint_K >= flange[0] else -1.0
    after = averaged_t >= ramp_end
    overshoot = float(max(direction * (averaged[after] - setpoint_K).max(initial=0.0), 0.0))
    window = times >= times[-1] - WINDOW_S
    metrics = regulation_metrics(times[window], flange[window], arrays["stage"][part][window],
                                 np.full(window.sum(), setpoint_K), line_rad_s)
    amplitude = metrics["ptc_periodic_amplitude_K"]
    reachable = max(limit.ptc_periodic_limit_K, limit.predicted_best_residual_K)
    return {"setpoint_K": setpoint_K, "settle_from_command_s": settled_at - start_s,
            "settle_from_ramp_end_s": settled_at - ramp_end, "ramp_s": ramp_end - start_s,
            "overshoot_mK": overshoot * 1e3, "mean_error_mK": metrics["mean_error_K"] * 1e3,
            "periodic_uK": amplitude * 1e6, "open_line_uK": limit.open_line_K * 1e6,
            "limit_uK": limit.ptc_periodic_limit_K * 1e6, "reachable_uK": reachable * 1e6,
            "over_limit": amplitude / reachable, "limited_by": limit.limited_by,
            "mean_heater_W": float(np.mean(arrays["heater"][part][window]))}


def hold_windows(arrays: dict, setpoint_K: float, start_s: float, end_s: float, line_rad_s: float,
                 noise_rms_K: float, period_s: float) -> dict:
    """The periodic amplitude of each consecutive ``WINDOW_S`` of the hold after its ramp, and of the hold from
    ``LONG_WINDOW_FROM_S`` after the ramp to its end as one window, with the noise floor of each length: a line
    left by the feedforward stays when the window grows, the noise of the estimate falls as its square root."""
    part = (arrays["times"] >= start_s) & (arrays["times"] < end_s)
    times, flange, stage = arrays["times"][part], arrays["flange"][part], arrays["stage"][part]
    ramp_end = times[np.flatnonzero(arrays["setpoint"][part] == setpoint_K)[0]]

    def amplitude(inside) -> float:
        metrics = regulation_metrics(times[inside], flange[inside], stage[inside], np.full(inside.sum(), setpoint_K),
                                     line_rad_s)
        return metrics["ptc_periodic_amplitude_K"] * 1e6

    starts = np.arange(ramp_end, times[-1] - WINDOW_S + 1e-6, WINDOW_S)
    each = [{"from_ramp_end_s": float(first - ramp_end),
             "periodic_uK": amplitude((times >= first) & (times < first + WINDOW_S))} for first in starts]
    long_inside = times >= ramp_end + LONG_WINDOW_FROM_S
    long_s = float(times[long_inside][-1] - times[long_inside][0]) if long_inside.any() else 0.0
    return {"each": each, "long_window_s": long_s, "long_periodic_uK": amplitude(long_inside) if long_s > 0 else math.nan,
            "noise_floor_window_uK": noise_floor_K(noise_rms_K, WINDOW_S, period_s) * 1e6,
            "noise_floor_long_uK": noise_floor_K(noise_rms_K, long_s, period_s) * 1e6 if long_s > 0 else math.nan}


def table(run: dict) -> str:
    lines = ["| setpoint | ramp (s) | within 1 mK after command (s) | after ramp end (s) | overshoot (mK) | "
             "periodic (µK) | open line (µK) | limit / reachable (µK) | periodic / reachable | heater (W) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    def seconds(value) -> str:
        return f"{value:.0f}" if value is not None and math.isfinite(value) else f"not by the end ({HOLD_AFTER_RAMP_S:.0f} s after the ramp)"

    for row in run["setpoints"]:
        lines.append(f"| {row['setpoint_K']:g} K | {row['ramp_s']:.0f} | {seconds(row['settle_from_command_s'])} | "
                     f"{seconds(row['settle_from_ramp_end_s'])} | {row['overshoot_mK']:.2f} | {row['periodic_uK']:.1f} | "
                     f"{row['open_line_uK']:.1f} | {row['limit_uK']:.2f} / {row['reachable_uK']:.2f} "
                     f"({row['limited_by']}) | {row['over_limit']:.2f} | {row['mean_heater_W']:.3f} |")
    ticks = run["tick_wall_ms"]
    lines.append(f"\nexit {run['exit_code']}, faults {run['faults']}, overruns {run['overruns']}, "
                 f"{run['simulated_h']:.2f} h simulated in {run['wall_s']:.0f} s; wall time per tick p50 "
                 f"{ticks['p50']:.2f} ms, p99 {ticks['p99']:.2f} ms, max {ticks['max']:.1f} ms; at the zone changes "
                 f"{', '.join(f'{value:.1f}' for value in ticks['zone_changes']) or '-'} ms")
    return "\n".join(lines)


def hold(args) -> dict:
    """One setpoint held long with the commissioned zones, for each seed: the spread of the periodic amplitude
    over windows and seeds, with the feedforward's model in the last zone as given."""
    if args.feedforward_model == "zone":
        top = None
    elif args.feedforward_model == "linearised":
        top = (args.split_K, linearised_at(load_model(TEMPERATURE_MODEL_PATH), args.setpoint),
               f"the simulated cryostat linearised at {args.setpoint:g} K")
    else:
        top = (args.split_K, load_model(args.feedforward_model), args.feedforward_model)
    report = {"feedforward_model": args.feedforward_model, "runs": []}
    for seed in (int(value) for value in args.seeds.split(",")):
        run = run_once(CONFIG, True, None, None, seed=seed, setpoints_K=(args.setpoint,), hold_after_ramp_s=args.hold,
                       top_zone=top, windows=True)
        report["runs"].append(run)
        row = run["setpoints"][0]
        windows = row["windows"]
        print(f"## seed {seed}, feedforward model {args.feedforward_model}\n\n{table(run)}\n", flush=True)
        print("periodic (uK) in each 300 s from the ramp's end: "
              + ", ".join(f"{item['from_ramp_end_s']:.0f} s {item['periodic_uK']:.2f}" for item in windows["each"]))
        print(f"over {windows['long_window_s']:.0f} s from {LONG_WINDOW_FROM_S:.0f} s after the ramp: "
              f"{windows['long_periodic_uK']:.2f} uK (noise floor {windows['noise_floor_long_uK']:.2f} uK; 300 s: "
              f"{windows['noise_floor_window_uK']:.2f} uK)", flush=True)
        print("feedforward events: " + " | ".join(run["feedforward_events"][-6:]) + "\n", flush=True)
    return report


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("commission", "run", "hold"))
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    parser.add_argument("--only", choices=("zones", "one set of gains"), default=None,
                        help="run: only this configuration (two processes for the two)")
    parser.add_argument("--setpoint", type=float, default=24.0, help="hold: the setpoint held (K)")
    parser.add_argument("--seeds", default="3", help="hold: the noise seeds, one run each (comma-separated)")
    parser.add_argument("--hold", type=float, default=HOLD_AFTER_RAMP_S, help="hold: how long after the ramp (s)")
    parser.add_argument("--feedforward-model", default="zone",
                        help="hold: the feedforward's model above --split-K: 'zone' (the table's), 'linearised' "
                             "(the simulated cryostat's tangent model at the setpoint), or a model file")
    parser.add_argument("--split-K", type=float, default=22.0, help="hold: where the last zone is split (K)")
    args = parser.parse_args()
    if args.what == "commission":
        report = commission()
    elif args.what == "hold":
        report = hold(args)
    else:
        first: ZoneTable = load_config(CONFIG).control.zones
        if first is None:
            print("config/cryod-4-25K.yaml has no zones: run commission first", file=sys.stderr)
            return 2
        report = {}
        for name, zones in (("zones", True), ("one set of gains", False)):
            if args.only not in (None, name):
                continue
            run = run_once(CONFIG, zones, first.zones[0].gains, first.zones[0].feedforward_model)
            report[name] = run
            print(f"## {name}\n\n{table(run)}\n", flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1, default=float).replace("Infinity", "null"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
