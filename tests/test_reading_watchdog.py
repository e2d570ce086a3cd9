"""The reading watchdog: a heater setting that outlives its readings is switched off from outside the loop.

The loop is stood in for by an object with the figures the watchdog reads; the clock is virtual and the test
moves it as a loop stuck in a call would let it move, while the watchdog's thread looks in real time.
"""

import dataclasses
import math
import threading
import time

import pytest

from cryod.config import load_config
from cryod.service.heater_guard import HeaterGuard, HeaterSwitchedOff
from cryod.service.faults import FaultCause, fault_from_instrument_error
from cryod.service.reading_watchdog import ReadingWatchdog
from drivers.clock import VirtualClock
from tests.conftest import CONFIG


class Supply:
    """The instruments as the guard sees them: what the heater was told, and when."""

    def __init__(self, clock):
        self.clock = clock
        self.log = []

    def set_heater_power(self, power_w):
        self.log.append(("set", power_w))

    def heater_off(self):
        self.log.append(("off", self.clock.now()))
        return self.clock.now()


@dataclasses.dataclass
class StuckLoop:
    config: object
    heater_w: float = 0.12
    heater_reading_s: float = 10.0
    period_s: float = 0.08


@pytest.fixture
def bench():
    config = load_config(CONFIG / "cryod.yaml")
    clock = VirtualClock(10.05)
    supply = Supply(clock)
    guard = HeaterGuard(supply)
    events = []
    loop = StuckLoop(config)
    watchdog = ReadingWatchdog(loop, guard, clock, events.append, wait_s=1.0)
    return clock, supply, guard, loop, watchdog, events


def test_a_setting_older_than_the_bound_is_switched_off_once_and_the_loops_next_setting_refused(bench):
    clock, supply, guard, loop, watchdog, events = bench
    assert loop.config.safety.max_reading_age_s == 0.5
    watchdog.look()
    assert supply.log == []                                    # 50 ms: a fresh setting
    clock.advance(0.44)
    watchdog.look()
    assert supply.log == []                                    # 0.49 s: within the bound
    clock.advance(0.02)
    watchdog.look()
    watchdog.look()                                            # once, however often it looks
    assert supply.log == [("off", pytest.approx(10.51))]
    assert len(events) == 1 and events[0].kind == "watchdog"
    assert "readings 0.510 s old" in events[0].message and "(safety.max_reading_age_s 0.5)" in events[0].message
    with pytest.raises(HeaterSwitchedOff) as refused:          # the loop comes back: it must recover first
        guard.set_heater_power(0.1)
    assert fault_from_instrument_error(refused.value).cause is FaultCause.READINGS_TOO_OLD
    guard.set_heater_power(0.1)                                # once: after the fault the loop may heat again
    assert supply.log[-1] == ("set", 0.1)


def test_a_heater_at_zero_or_switched_off_by_the_loop_is_left_alone(bench):
    clock, supply, guard, loop, watchdog, events = bench
    loop.heater_w = 0.0
    clock.advance(5.0)
    watchdog.look()
    loop.heater_w, loop.heater_reading_s = math.nan, math.nan    # unknown: the loop is stopping for it
    watchdog.look()
    assert supply.log == [] and events == []
    loop.heater_w, loop.heater_reading_s = 0.1, clock.now() - 1.0
    guard.switch_off_if(lambda: True, "earlier", 1.0)
    guard.heater_off()                                         # the loop switched it off itself since: said
    assert guard.switched_off is None
    guard.set_heater_power(0.05)                               # nothing left to refuse
    assert supply.log[-1] == ("set", 0.05)


def test_the_watchdogs_thread_switches_off_a_stuck_loops_heater_within_the_bound(bench):
    """The loop stands still in a call while the clock runs (the test moves it 10 ms at a time): the heater is
    off before the readings behind it are 0.5 s and a look's spacing (20 ms) old."""
    clock, supply, guard, loop, watchdog, events = bench
    watchdog.start()
    try:
        for _ in range(100):
            clock.advance(0.01)
            time.sleep(0.005)
            if supply.log:
                break
        deadline = time.monotonic() + 2.0
        while not supply.log and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        watchdog.stop()
    assert supply.log and supply.log[0][0] == "off"
    assert 10.5 < supply.log[0][1] <= 10.5 + 0.02 + 0.02 + 1e-9       # bound, a look's spacing, a step of the test
    assert watchdog.switched_off == 1


def test_a_call_of_the_loop_in_progress_is_waited_for_and_the_age_looked_at_again(bench):
    """The loop sets the heater from fresh readings while the watchdog waits for the supply: nothing is switched."""
    clock, supply, guard, loop, watchdog, events = bench
    clock.advance(1.0)
    in_call = threading.Event()
    release = threading.Event()

    def slow_set(power_w):
        in_call.set()
        release.wait(5.0)
        loop.heater_reading_s = clock.now()                   # the setting came from fresh readings after all
        supply.log.append(("set", power_w))

    supply.set_heater_power = slow_set
    setter = threading.Thread(target=guard.set_heater_power, args=(0.2,))
    setter.start()
    in_call.wait(5.0)
    looker = threading.Thread(target=watchdog.look)
    looker.start()
    time.sleep(0.05)
    release.set()
    setter.join(5.0)
    looker.join(5.0)
    assert supply.log == [("set", 0.2)] and events == []
