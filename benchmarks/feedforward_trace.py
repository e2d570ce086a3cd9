"""The feedforward term taken through every one of its states, tick by tick: a trace to compare two checkouts.

Run: PYTHONPATH=. python3 benchmarks/feedforward_trace.py [--out FILE] [--against OTHER_CHECKOUT]

Ticks go straight into a ``FeedforwardTerm`` on the shipped model (as ``tests/feedforward_ticks.py``
gives them: T5 with the cooler's line, T2 with its line and what the heater played the tick before
through the term's plant, or through a plant turned by 180 degrees and turning, which the learning
cannot follow), on a script that visits each state: locking, fading in, probing, learning,
tracking; switched off and on; the loop's cycles late and on time again; the cooler stopped (the
lock lost) and back; a gap in the loop; a divergence, its fade-out and the wait before the retry
(with late cycles during the wait); a second divergence switched off while it fades out; reloads
(another learning gain, margin, controller's model; off and on through ``enabled``; no probe); another
zone; the loop open for a while and closed again.

Every tick writes the term's output, its record columns and its events (``repr``, so every bit of
every float), every 2 s its status text (``describe()``), and at the end ``learning_summary()``.
The computation is deterministic (the learning worker's results do not depend on the threads'
timing), so two checkouts that behave the same write the same file: ``--against`` runs the
script on the other checkout too and compares.

Results: ``benchmarks/results/loop_cpu.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

OMEGA = 10.83           # the cooler's line, rad/s
PERIOD = 0.08           # the loop's period, s


def trace(out) -> None:
    """The script, written to ``out`` (a text file)."""
    import numpy as np

    from cryod.control.feedforward import FeedforwardSettings, FeedforwardTerm
    from cryod.control.terms import TickInputs
    from cryod.model import DEFAULT_MODEL_PATH, load_model

    model = load_model(DEFAULT_MODEL_PATH)
    settings = FeedforwardSettings(model=model, retry_after_s=30.0)
    term = FeedforwardTerm(settings, 0.5)
    term.start(None, 0.113)
    run = {"time_s": 0.0, "answer": np.zeros(settings.harmonics, dtype=complex), "ticks": 0}

    def feed(seconds, cooler=True, plant=None, skip_s=0.0, closed=True):
        """Ticks for ``seconds``; ``skip_s`` leaves a gap in the loop before the first; ``closed`` False: the
        loop open (manual power: the term conditions T2 but plays nothing)."""
        orders = np.arange(1, term.settings.harmonics + 1)
        run["time_s"] += skip_s
        for k in range(int(round(seconds / PERIOD))):
            t = run["time_s"]
            stage_K = 3.34 + (0.12 * math.cos(OMEGA * t) if cooler else 0.0)
            played_K = float(np.real(np.sum(run["answer"] * np.exp(1j * orders * OMEGA * t))))
            tick = TickInputs.at(t, PERIOD + (skip_s if k == 0 else 0.0),
                                 5.0 + 1.7e-3 * math.cos(OMEGA * t - 1.1) + played_K, stage_K, 5.0,
                                 output_time_s=t + 0.03)
            tick = term.condition(tick)
            output_w = term.update(tick) if closed else 0.0
            if closed:
                term.limit(0.113 + output_w, min(0.113 + output_w, 0.5))
            response = term.plant if plant is None else plant
            run["answer"] = response * (term.coefficients + term.probe) * (term.scale if output_w else 0.0)
            out.write(f"{t!r} {output_w!r} {term.column_values()!r} {term.take_events()!r}\n")
            if run["ticks"] % 25 == 0:
                out.write(term.describe() + "\n")
            run["ticks"] += 1
            run["time_s"] = t + PERIOD
        out.write("== " + term.describe() + "\n")

    def until_diverged(model_plant, divergences):
        for second in range(150):               # a turn of 180 degrees, then a turn a minute
            feed(1.0, plant=model_plant * np.exp(1j * (math.pi + 2.0 * math.pi * second / 60.0)))
            if term.divergences >= divergences:
                return

    feed(90.0)
    term.switch(False)
    feed(10.0)
    term.switch(True)
    feed(15.0)
    term.follow_timing(False)
    feed(10.0)
    term.follow_timing(True)
    feed(15.0)
    feed(10.0, cooler=False)
    feed(15.0)
    feed(10.0, skip_s=1.0)
    model_plant = term.plant.copy()
    until_diverged(model_plant, 1)
    feed(10.0, plant=model_plant)
    term.follow_timing(False)
    feed(5.0, plant=model_plant)
    term.follow_timing(True)
    feed(50.0, plant=model_plant)
    until_diverged(model_plant, 2)
    term.switch(False)
    feed(10.0, plant=model_plant)
    term.switch(True)
    feed(90.0, plant=model_plant)
    term.reconfigure(dataclasses.replace(settings, learning_gain=0.3), 0.5)
    feed(10.0)
    term.reconfigure(dataclasses.replace(settings, margin_W=0.002), 0.45)
    feed(20.0)
    term.enter_zone(1)
    feed(30.0)
    stronger = dataclasses.replace(model, heater_to_flange=dataclasses.replace(
        model.heater_to_flange, numerator=tuple(1.5 * c for c in model.heater_to_flange.numerator)))
    term.reconfigure(dataclasses.replace(settings, model=stronger), 0.45)
    feed(20.0)
    term.reconfigure(dataclasses.replace(settings, enabled=False), 0.5)
    feed(10.0)
    term.reconfigure(dataclasses.replace(settings, enabled=True), 0.5)
    feed(20.0)
    feed(5.0, closed=False)
    term.start(None, 0.113)
    feed(20.0)
    term.reconfigure(dataclasses.replace(settings, probe_amplitude_K=0.0), 0.5)
    feed(40.0)
    out.write(repr(term.learning_summary()) + "\n")
    term.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, help="the trace (default: a temporary file)")
    parser.add_argument("--against", type=Path, help="another checkout: run the script there too and compare")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        out = args.out or Path(folder) / "trace.txt"
        with out.open("w", encoding="utf-8") as stream:
            trace(stream)
        ticks = sum(1 for line in out.open(encoding="utf-8") if line[:1].isdigit())
        print(f"{ticks} ticks traced into {out}" if args.out else f"{ticks} ticks traced")
        if args.against is None:
            return 0
        other = Path(folder) / "other.txt"
        subprocess.run([sys.executable, str(Path(__file__).resolve()), "--out", str(other)],
                       cwd=args.against, env={**os.environ, "PYTHONPATH": str(args.against.resolve())}, check=True,
                       capture_output=True)
        ours, theirs = out.read_text(encoding="utf-8").splitlines(), other.read_text(encoding="utf-8").splitlines()
        if ours == theirs:
            print(f"the same as {args.against}, every line")
            return 0
        first = next((index for index, (a, b) in enumerate(zip(ours, theirs)) if a != b), min(len(ours), len(theirs)))
        print(f"differs from {args.against} from line {first + 1} ({len(ours)} against {len(theirs)} lines):\n"
              f"  here:  {ours[first] if first < len(ours) else '(end)'}\n"
              f"  there: {theirs[first] if first < len(theirs) else '(end)'}")
        return 1


if __name__ == "__main__":
    sys.exit(main())
