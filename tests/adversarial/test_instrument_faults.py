"""Adversarial run over the instrument faults: how long the heater really stays on, measured at the supply.

Every category runs the whole daemon in real time against the simulated instruments over TCP
(tests/fault_drills.py) a few times; the simulated supply's own log gives the instant the heater
reached 0 W. Each run must have it there within ``InstrumentWaits.fault_to_off_s`` (one loop
period, the reading's own time, one loop-path reply, the heater-off) plus ALLOWANCE_S for a loaded
machine, its record must never say 0 W before the supply was there, and a heater-off sent while the
loop recovers, a stop asked for after it and the watchdog must each be served within the longest
tick. The table of figures is printed (docs/explanation/safety.md, "What each instrument fault does"):

    .venv/bin/python -m pytest -m slow tests/adversarial/test_instrument_faults.py
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import pytest

from cryod.instrument_waits import InstrumentWaits
from tests.fault_drills import TcpFaultDrill, never_claims_zero_early, reading_delay_s

ALLOWANCE_S = 0.5
RUNS = 3


@dataclass(frozen=True)
class Category:
    name: str
    fault: str
    timeout_s: float = 1.0
    prologix: bool = False
    exit_code: int = 0          # 6: the supply cannot confirm the off (its state is unknown)

    @property
    def recovers(self) -> bool:
        return self.exit_code == 0


LARGEST_TIMEOUT_S = round(InstrumentWaits(0.08, 1.0).largest_timeout_s(), 3)
CATEGORIES = [
    Category("silent flange DMM", "silent flange DMM", 0.5),
    Category("silent flange DMM", "silent flange DMM", 1.0),
    Category("silent flange DMM", "silent flange DMM", LARGEST_TIMEOUT_S),
    Category("silent PTC-stage DMM", "silent PTC-stage DMM"),
    Category("garbage from the flange DMM", "garbage from the flange DMM"),
    Category("silent heater supply", "silent heater supply", exit_code=6),
    Category("garbage from the heater supply", "garbage from the heater supply", exit_code=6),
    Category("every link drops (a TCP port each)", "every link drops at once"),
    Category("every link drops (one Prologix controller)", "every link drops at once", prologix=True),
]


def run_category(tmp_path, category: Category, run: int):
    """One drill; returns (figures, problems)."""
    drill = TcpFaultDrill(tmp_path / f"{run}", category.fault, timeout_s=category.timeout_s,
                          prologix=category.prologix, fault_at_row=15 + 3 * run, after_fault_s=4.0,
                          heater_off_after_s=0.5 if category.recovers else None,
                          stop_after_s=1.5 if category.recovers else None)
    result = drill.run()
    waits = drill.waits
    bound = waits.fault_to_off_s(reading_delay_s(drill.daemon.loop))
    supply = drill.opener.bench.heater_supply
    problems = []
    where = f"{category.name}, timeout_s {category.timeout_s:g}, run {run}"
    if result.exit_code != category.exit_code:
        problems.append(f"{where}: exit {int(result.exit_code)}, expected {category.exit_code}")
    if result.fault_to_off_s is None or result.fault_to_off_s > bound + ALLOWANCE_S:
        problems.append(f"{where}: supply at 0 W {result.fault_to_off_s} s after the fault (bound {bound:.3f} s)")
    problems += [f"{where}: {problem}" for problem in never_claims_zero_early(result, supply.power_at)]
    recorded_late_ms = None
    if result.off_row is not None and result.real_off_s is not None and result.off_row.heater_W == 0.0:
        recorded_late_ms = (result.off_row.time_s - result.real_off_s) * 1e3
        if recorded_late_ms < 0.0:
            problems.append(f"{where}: the record says 0 W {-recorded_late_ms:.3f} ms before the supply was there")
    answer_s = stop_s = None
    if category.recovers:
        answer_s = result.heater_off_answer_s - result.heater_off_sent_s
        stop_s = result.stop_event_s - result.stop_requested_s
        for what, value in (("heater-off answered", answer_s), ("stop honoured", stop_s)):
            if value > waits.longest_tick_s + ALLOWANCE_S:
                problems.append(f"{where}: {what} after {value:.3f} s (longest tick {waits.longest_tick_s:.3f} s)")
    else:
        stop_s = result.stop_event_s - result.fault_s          # the stop tick, from the fault
        if stop_s > bound + ALLOWANCE_S:
            problems.append(f"{where}: stop {stop_s:.3f} s after the fault (bound {bound:.3f} s)")
        if result.events[-1].kind != "stop":
            problems.append(f"{where}: {result.events[-1].text!r} after the stop event")
    gap = max(result.watchdog_gaps_s, default=0.0)
    if gap > waits.longest_tick_s + ALLOWANCE_S:
        problems.append(f"{where}: watchdog unfed for {gap:.3f} s (longest tick {waits.longest_tick_s:.3f} s)")
    return dict(off_s=result.fault_to_off_s, bound_s=bound, late_ms=recorded_late_ms, answer_s=answer_s,
                stop_s=stop_s, gap_s=gap, exit=int(result.exit_code)), problems


def table(figures: dict) -> str:
    lines = ["| fault | timeout_s | exit | fault to supply at 0 W: median, max (s) | bound (s) | record's 0 W after "
             "the supply's, max (ms) | heater-off answered, max (s) | stop, max (s) | watchdog gap, max (s) |",
             "|---|---|---|---|---|---|---|---|---|"]

    def largest(values, digits=3):
        values = [value for value in values if value is not None]
        return f"{max(values):.{digits}f}" if values else "-"

    for category, runs in figures.items():
        offs = [run["off_s"] for run in runs if run["off_s"] is not None]
        lines.append(
            f"| {category.name} | {category.timeout_s:g} | {runs[0]['exit']} | "
            f"{statistics.median(offs):.3f}, {max(offs):.3f} | {runs[0]['bound_s']:.3f} | "
            f"{largest([run['late_ms'] for run in runs], 2)} | {largest([run['answer_s'] for run in runs])} | "
            f"{largest([run['stop_s'] for run in runs])} | {largest([run['gap_s'] for run in runs])} |")
    return "\n".join(lines)


@pytest.mark.slow
def test_every_instrument_fault_has_the_heater_really_at_0_W_within_the_loops_bound(tmp_path, capsys):
    figures, problems = {}, []
    for category in CATEGORIES:
        figures[category] = []
        for run in range(RUNS):
            measured, found = run_category(tmp_path / f"{len(figures)}", category, run)
            figures[category].append(measured)
            problems += found
    with capsys.disabled():
        print("\n" + table(figures))
    assert problems == []
