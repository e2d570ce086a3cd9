"""A direct instrument set on the simulated cryostat, for testing the loop's logic without SCPI.

The fault tests through the real drivers and the simulated instruments are in
test_daemon_faults.py; this double only lets loop tests script faults exactly. ``make_loop`` builds
the daemon's loop on it and a virtual clock, with the example configuration's sensor curves
(``example_curves``).
"""

from __future__ import annotations

import functools
import math

from cryod.records.columns import Row
from cryod.service.loop import ControlLoop
from cryod.thermometry import load_calibration
from drivers.clock import VirtualClock
from drivers.thermometer_pair import PairReading
from simulated_hw.cryostat import SimulatedCryostat
from tests.conftest import CONFIG


@functools.cache
def example_curves():
    """The flange's (T2) and the cooler stage's (T5) calibration curves of the example configuration."""
    return (load_calibration(CONFIG / "calibration" / "X186279.340"),
            load_calibration(CONFIG / "calibration" / "X207058.340"))


def make_loop(reference_model, curves, config, **instrument_options):
    """The loop on :class:`DirectInstruments` and a virtual clock: (loop, instruments, cryostat, rows, events)."""
    clock = VirtualClock()
    cryostat = SimulatedCryostat(reference_model, clock, seed=2)
    instruments = DirectInstruments(cryostat, *curves, clock, **instrument_options)
    rows, events = [], []
    loop = ControlLoop(config, instruments, *curves, clock,
                       emit=lambda item: (rows if isinstance(item, Row) else events).append(item))
    return loop, instruments, cryostat, rows, events


def tick_rows(rows):
    """The rows that stand for a tick: without the heater-off's own rows (no lateness: no tick)."""
    return [row for row in rows if not math.isnan(row.lateness_ms)]


def heater_off_rows(rows):
    """The rows of the instants the supply confirmed a heater-off (or found it could not)."""
    return [row for row in rows if math.isnan(row.lateness_ms)]


class DirectInstruments:
    """Reads the simulated cryostat through the calibration curves; faults scripted per call."""

    def __init__(self, cryostat, flange_curve, ptc_stage_curve, clock, measure_time_s=0.03):
        self.cryostat = cryostat
        self.flange_curve = flange_curve
        self.ptc_stage_curve = ptc_stage_curve
        self.clock = clock
        self.measure_time_s = measure_time_s
        self.measure_faults: dict[int, BaseException] = {}
        self.heater_faults: dict[int, BaseException] = {}
        self.measure_delays: dict[int, float] = {}
        self.resistance_override: dict[int, tuple[float, float]] = {}
        self.heater_off_error: BaseException | None = None      # the supply out of reach: it keeps its current
        self.measurements = 0
        self.heater_writes = 0
        self.heater_log: list[tuple[float, float]] = []
        self.reconnects = 0
        self.closed = False

    def measure(self) -> PairReading:
        call = self.measurements
        self.measurements += 1
        trigger = self.clock.now()
        if call in self.measure_faults:
            raise self.measure_faults[call]
        flange_K, stage_K = self.cryostat.read_temperatures()
        self.clock.sleep_until(trigger + self.measure_time_s + self.measure_delays.get(call, 0.0))
        flange_ohm = float(self.flange_curve.resistance_ohm(flange_K))
        stage_ohm = float(self.ptc_stage_curve.resistance_ohm(stage_K))
        flange_ohm, stage_ohm = self.resistance_override.get(call, (flange_ohm, stage_ohm))
        return PairReading(trigger, 0.0, flange_ohm, stage_ohm, self.clock.now(), trigger, trigger)

    def set_heater_power(self, power_w: float) -> None:
        call = self.heater_writes
        self.heater_writes += 1
        if call in self.heater_faults:
            raise self.heater_faults[call]
        self.cryostat.set_heater_power(power_w)
        self.heater_log.append((self.clock.now(), power_w))

    def heater_off(self) -> float:
        if self.heater_off_error is not None:
            raise self.heater_off_error
        self.cryostat.set_heater_power(0.0)
        self.heater_log.append((self.clock.now(), 0.0))
        return self.clock.now()

    def examine(self, error) -> None:
        error.examine()

    def reconnect(self) -> None:
        self.reconnects += 1

    def close(self) -> None:
        self.heater_off()
        self.closed = True
