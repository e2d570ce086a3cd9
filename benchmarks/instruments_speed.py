"""Cost of one measurement cycle through the real drivers and the simulated instruments.

One cycle is what cryod does every 80 ms: trigger both thermometer DMMs,
fetch both resistances (:class:`drivers.thermometer_pair.ThermometerPair`),
then set the heater (:meth:`drivers.heater.HeaterSupply.set_power_w`).

* in process, on a VirtualClock: the CPU time of a cycle (no waiting: the
  virtual clock jumps over the integration) — what bounds
  ``cryod --simulate --speed max``;
* over TCP sockets on 127.0.0.1 through pyvisa-py, on the real clock, with
  ``*TRG`` in turn: the wall time of a cycle and what it costs beyond the
  DMMs' integration and processing time (``reading_delay_s``);
* through the simulated Prologix GPIB-ETHERNET controller with its group
  trigger, likewise.

Usage::

    python3 benchmarks/instruments_speed.py [--cycles N]

It prints one line per setup: median and 95th percentile in ms. The result
on the project's reference machine is in ``benchmarks/results/instruments_speed.md``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPOSITORY))

from drivers.clock import MonotonicClock, VirtualClock  # noqa: E402
from drivers.keithley2002 import FourWireSettings, Keithley2002  # noqa: E402
from drivers.keithley6221 import Keithley6221  # noqa: E402
from drivers.pair_triggers import HardwareTrigger, PrologixGroupTrigger, SequentialTrigger  # noqa: E402
from drivers.thermometer_pair import ThermometerPair  # noqa: E402
from drivers.transports import PrologixAdapter, VisaTransport  # noqa: E402
from drivers.trigger_lines import SerialControlLine  # noqa: E402
from simulated_hw.bench import PROLOGIX_ADDRESSES, SimulatedBench  # noqa: E402

FLANGE = FourWireSettings(range_ohm=20e3, nplc=1.0)
STAGE = FourWireSettings(range_ohm=2e3, nplc=1.0)
HEATER_RESISTANCE_OHM = 50.0


def build(clock, transports, heater_transport, trigger_for):
    flange = Keithley2002(transports[0], clock, "flange DMM")
    stage = Keithley2002(transports[1], clock, "PTC-stage DMM")
    flange.configure_four_wire_resistance(FLANGE)
    stage.configure_four_wire_resistance(STAGE)
    pair = ThermometerPair(flange, stage, trigger_for(transports), clock)
    heater = Keithley6221(heater_transport, clock, HEATER_RESISTANCE_OHM, name="flange heater")
    return pair, heater


def run_cycles(pair, heater, cycles, clock, period_s=0.08):
    """Wall time of each cycle (s); cycles start every ``period_s`` on ``clock``."""
    pair.measure()                      # first reading after configuration waits longer: not counted
    durations = []
    start = clock.now()
    for cycle in range(cycles):
        clock.sleep_until(start + (cycle + 1) * period_s)
        began = time.perf_counter()
        pair.measure()
        heater.set_power_w(0.05 + 0.01 * (cycle % 5))
        durations.append(time.perf_counter() - began)
    return durations


def summary(name, durations, pair=None):
    """Median and 95th percentile; with ``pair``, the median's excess over the earliest reading time."""
    durations_ms = sorted(d * 1e3 for d in durations)
    median = statistics.median(durations_ms)
    p95 = durations_ms[int(0.95 * (len(durations_ms) - 1))]
    extra = ""
    if pair is not None:
        earliest = pair.flange_dmm.earliest_reading_delay_s * 1e3
        extra = (f"   (readings take {earliest:.0f} to {pair.reading_delay_s * 1e3:.0f} ms; "
                 f"median beyond {earliest:.0f} ms: {median - earliest:.2f} ms)")
    return f"{name:<42} median {median:6.2f} ms   95th percentile {p95:6.2f} ms{extra}"


def in_process(cycles):
    clock = VirtualClock()
    bench = SimulatedBench(clock, seed=1, heater_resistance_ohm=HEATER_RESISTANCE_OHM)
    links = bench.in_process_transports()
    pair, heater = build(clock, (links.flange_dmm, links.ptc_stage_dmm), links.heater_supply,
                         lambda t: HardwareTrigger(SerialControlLine(bench.trigger_port, clock), clock))
    return summary("in process, VirtualClock (CPU time)", run_cycles(pair, heater, cycles, clock))


def over_sockets(cycles):
    clock = MonotonicClock()
    bench = SimulatedBench(clock, seed=1, heater_resistance_ohm=HEATER_RESISTANCE_OHM)
    with bench.serve_tcp() as resources:
        transports = (VisaTransport(resources["flange_dmm"]), VisaTransport(resources["ptc_stage_dmm"]))
        pair, heater = build(clock, transports, VisaTransport(resources["heater_supply"]),
                             lambda t: SequentialTrigger(t, clock))
        durations = run_cycles(pair, heater, cycles, clock)
        heater.close()
        pair.close()
    return summary("TCP sockets via pyvisa-py, *TRG in turn", durations, pair)


def through_prologix(cycles):
    clock = MonotonicClock()
    bench = SimulatedBench(clock, seed=1, heater_resistance_ohm=HEATER_RESISTANCE_OHM)
    with bench.serve_prologix() as controller:
        adapter = PrologixAdapter(controller.interface_resource_name)
        transports = (adapter.instrument(PROLOGIX_ADDRESSES["flange"]),
                      adapter.instrument(PROLOGIX_ADDRESSES["ptc_stage"]))
        addresses = [PROLOGIX_ADDRESSES["flange"], PROLOGIX_ADDRESSES["ptc_stage"]]
        pair, heater = build(clock, transports, adapter.instrument(PROLOGIX_ADDRESSES["heater"]),
                             lambda t: PrologixGroupTrigger(adapter, addresses, clock))
        durations = run_cycles(pair, heater, cycles, clock)
        heater.close()
        pair.close()
        adapter.close()
    return summary("Prologix (simulated) via pyvisa-py, ++trg", durations, pair)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=200, help="cycles per setup (default 200)")
    args = parser.parse_args()
    print(in_process(args.cycles * 10))
    print(over_sockets(args.cycles))
    print(through_prologix(args.cycles))


if __name__ == "__main__":
    main()
