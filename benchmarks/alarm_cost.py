"""CPU time the alarms cost the loop's thread per row, against the live view's tap in the same process.

Run: PYTHONPATH=. python3 benchmarks/alarm_cost.py [--rows N] [--window S]

The alarm monitor (``cryod/service/alarms.py``) runs on the loop's thread as its last row tap. Rows as
the loop makes them (T2 at its setpoint with the cooler's line, T5 with its 0.12 K oscillation) go to
three taps in turn, each timed with ``time.thread_time`` over all rows, the best of three runs: the
live view (the baseline every run already has), the monitor with every alarm on (``--window`` for
the deviation and stability windows), and the monitor with none on. The slowest single row of the
monitor is the once-a-second check of the windows, timed alone with ``time.thread_time``.

Results: ``benchmarks/results/loop_cpu.md`` (the figures measured, with the command, the machine and its
load; update it when this benchmark's results change).
"""

from __future__ import annotations

import argparse
import json
import math
import time

from cryod.alarms.settings import (AlarmsConfig, CoolerLineLostAlarm, DeviationAlarm, HeaterNearTopAlarm,
                                   PtcStageWarmAlarm, StabilityAlarm)
from cryod.records.columns import Row
from cryod.service.alarms import AlarmMonitor
from cryod.service.live_view import LiveView

PERIOD_S = 0.08
COOLER_RAD_S = 10.83


def rows(count: int) -> list[Row]:
    made = []
    for tick in range(1, count + 1):
        t = tick * PERIOD_S
        made.append(Row(time_s=t, lateness_ms=0.1, state="closed", T2_K=5.0 + 4e-4 * math.sin(COOLER_RAD_S * t),
                        T5_K=3.6 + 0.12 * math.sin(COOLER_RAD_S * t + 1.1), heater_W=0.11, setpoint_K=5.0,
                        T2_sample_s=t))
    return made


def every_alarm(window_s: float) -> AlarmsConfig:
    return AlarmsConfig(deviation=DeviationAlarm(threshold_K=1e-3, window_s=window_s),
                        stability=StabilityAlarm(threshold_K=2e-3, window_s=window_s),
                        ptc_stage_warm=PtcStageWarmAlarm(threshold_K=4.5), heater_near_top=HeaterNearTopAlarm(),
                        cooler_line_lost=CoolerLineLostAlarm())


def cpu_per_row_us(tap, made: list[Row]) -> float:
    start = time.thread_time()
    for row in made:
        tap(row)
    return (time.thread_time() - start) / len(made) * 1e6


def slowest_rows_us(window_s: float, made: list[Row]) -> tuple[float, float]:
    """The monitor's CPU for its slowest row and the 99.9th percentile (thread CPU time, so that the other
    processes of a shared machine do not count)."""
    monitor = AlarmMonitor(every_alarm(window_s), 0.5, COOLER_RAD_S, PERIOD_S)
    spent = []
    for row in made:
        start = time.thread_time()
        monitor(row)
        spent.append(time.thread_time() - start)
    spent.sort()
    return spent[-1] * 1e6, spent[int(len(spent) * 0.999)] * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=45_000, help="rows per run (default: an hour at 80 ms)")
    parser.add_argument("--window", type=float, default=60.0, help="deviation and stability window, s")
    args = parser.parse_args()
    made = rows(args.rows)
    results = {"live view": [], "alarms, all on": [], "alarms, none on": []}
    for _ in range(3):
        results["live view"].append(cpu_per_row_us(LiveView(PERIOD_S, COOLER_RAD_S), made))
        results["alarms, all on"].append(cpu_per_row_us(
            AlarmMonitor(every_alarm(args.window), 0.5, COOLER_RAD_S, PERIOD_S), made))
        results["alarms, none on"].append(cpu_per_row_us(AlarmMonitor(AlarmsConfig(), 0.5, COOLER_RAD_S, PERIOD_S),
                                                         made))
    best = {name: min(values) for name, values in results.items()}
    print(json.dumps({"rows": args.rows, "window_s": args.window,
                      "cpu_us_per_row": {name: round(value, 2) for name, value in best.items()},
                      "alarms_all_on_over_live_view": round(best["alarms, all on"] / best["live view"], 1),
                      "slowest_row_cpu_us, p99.9": [round(value, 1) for value in slowest_rows_us(args.window, made)]}))


if __name__ == "__main__":
    main()
