"""Command line: ``cryod --simulate`` (dry run on the simulated cryostat)."""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from cryod.clock import VirtualClock
from cryod.line_fit import fit_line
from cryod.model import DEFAULT_MODEL_PATH, load_model
from cryod.yaml_source import FileFormatError

LOOP_PERIOD_S = 0.08

#: Subcommands with their own module (``configure_parser(parser)`` and ``run(args) -> int``).
SUBCOMMANDS = {"analyze": "cryod.analysis.command", "identify": "cryod.identification.command"}


def run_subcommand(name: str, argv: list[str]) -> int:
    """``cryod <name> ...`` for a subcommand module of :data:`SUBCOMMANDS`."""
    import importlib

    module = importlib.import_module(SUBCOMMANDS[name])
    parser = module.configure_parser(argparse.ArgumentParser(prog=f"cryod {name}"))
    return module.run(parser.parse_args(argv))


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cryod",
        description="Temperature regulation of a pulse-tube cooled cryostat flange.",
    )
    parser.add_argument("--simulate", action="store_true",
                        help="run against the simulated cryostat instead of real instruments")
    parser.add_argument("--sim-model", default=str(DEFAULT_MODEL_PATH),
                        help="model file of the simulated cryostat (default: the shipped model)")
    parser.add_argument("--duration", type=float, default=600.0, help="simulated seconds to run")
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise seed")
    parser.add_argument("--json", action="store_true", help="print one summary object on stdout")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in SUBCOMMANDS:
        return run_subcommand(argv[0], argv[1:])
    args = _parser().parse_args(argv)
    if not args.simulate:
        _parser().print_help(sys.stderr)
        return 2
    try:
        model = load_model(args.sim_model)
    except FileFormatError as error:
        print(f"cryod: {error}", file=sys.stderr)
        return 2
    from simulated_hw.cryostat import SimulatedCryostat

    clock = VirtualClock()
    cryostat = SimulatedCryostat(model, clock, seed=args.seed)
    started = time.perf_counter()
    ticks = int(round(args.duration / LOOP_PERIOD_S))
    times = np.empty(ticks)
    flange = np.empty(ticks)
    stage = np.empty(ticks)
    for tick in range(ticks):
        clock.sleep_until((tick + 1) * LOOP_PERIOD_S)
        times[tick] = clock.now()
        flange[tick], stage[tick] = cryostat.read_temperatures()
    wall = time.perf_counter() - started
    line = fit_line(times, flange, model.ptc.angular_frequency_rad_s)
    summary = {
        "duration_s": ticks * LOOP_PERIOD_S,
        "ticks": ticks,
        "wall_s": round(wall, 3),
        "mean_T2_K": float(np.mean(flange)),
        "mean_T5_K": float(np.mean(stage)),
        "ptc_line_amplitude_K": line.amplitude[0],
    }
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
