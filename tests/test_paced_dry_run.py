"""Dry runs faster than real time: the paced clock, its speed, and a run's results against virtual time."""

import io

import pytest

import cryod
from drivers.paced_clock import PacedClock
from cryod.service.status_line import format_status

#: Processes, real sockets or real time: the second step of the suite (pytest -m system).
pytestmark = pytest.mark.system


class FakeWall:
    """Real time that moves only when slept or worked through."""

    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        assert seconds > 0
        self.now += seconds


def test_a_machine_that_keeps_up_runs_at_the_speed_asked_for():
    wall = FakeWall()
    clock = PacedClock(20.0, wall=wall, sleep=wall.sleep)
    for tick in range(1, 1001):
        wall.now += 0.001                       # a tick's work: 1 ms of the 4 ms a period takes at speed 20
        clock.sleep_until(0.08 * tick)
        assert clock.now() == pytest.approx(0.08 * tick)
    assert clock.achieved_speed() == pytest.approx(20.0, rel=1e-6)
    assert clock.recent_speed() == pytest.approx(20.0, rel=1e-6)
    assert clock.lag_given_up_s == 0.0


def test_a_machine_that_falls_behind_slows_the_simulated_clock_and_misses_no_deadline():
    wall = FakeWall()
    clock = PacedClock(20.0, wall=wall, sleep=wall.sleep)
    for tick in range(1, 1001):
        before = clock.now()
        wall.now += 0.010                       # 10 ms of work per 80 ms period: 8 times real time at best
        assert clock.now() == before            # work takes no simulated time: no tick ends after its deadline
        clock.sleep_until(0.08 * tick)
        assert clock.now() == pytest.approx(0.08 * tick)
    assert clock.achieved_speed() == pytest.approx(8.0, rel=0.01)
    assert clock.recent_speed() == pytest.approx(8.0, rel=0.01)
    assert clock.lag_given_up_s > 0.0


def test_a_short_stall_is_caught_up_and_a_long_one_given_up():
    wall = FakeWall()
    clock = PacedClock(10.0, max_lag_s=0.5, wall=wall, sleep=wall.sleep)
    clock.sleep_until(1.0)                      # 0.1 s of real time
    wall.now += 0.3                             # a stall shorter than the lag allowed: the next waits are skipped
    clock.sleep_until(2.0)
    clock.sleep_until(3.0)
    clock.sleep_until(4.0)
    assert wall.now == pytest.approx(100.4) and clock.lag_given_up_s == 0.0
    clock.sleep_until(5.0)                      # back on pace: waits again
    assert wall.now == pytest.approx(100.5)
    wall.now += 2.0                             # a long stall: given up, the pace restarts from here
    clock.sleep_until(6.0)
    assert clock.lag_given_up_s == pytest.approx(1.9)
    clock.sleep_until(7.0)
    assert wall.now == pytest.approx(102.6)
    assert clock.achieved_speed() == pytest.approx(7.0 / 2.6)


def test_the_status_line_shows_the_speed_achieved_and_the_overruns():
    snapshot = {"state": "closed", "T2_K": 5.0, "error_K": 1e-6, "T5_K": 3.4, "heater_W": 0.1,
                "line_amplitude_K": 5e-4, "faults": {}, "lateness_ms": 0.0, "overruns": 3, "achieved_speed": 17.26}
    assert format_status(snapshot).endswith("| overruns 3 | speed 17.3x")
    assert "overruns" not in format_status(dict(snapshot, overruns=0))


def test_a_paced_dry_run_over_tcp_matches_virtual_time_and_slows_instead_of_faulting(tmp_path):
    common = dict(setpoint_K=5.0, window_s=30.0, log_stream=io.StringIO())
    virtual = cryod.simulate(60.0, data_dir=tmp_path / "max", socket=tmp_path / "max.sock", **common)
    paced = cryod.simulate(60.0, speed=20.0, data_dir=tmp_path / "paced", socket=tmp_path / "paced.sock", **common)
    # far faster than any machine: the clock slows to what this one manages, and still no deadline is missed
    unreachable = cryod.simulate(60.0, speed=1e6, data_dir=tmp_path / "fast", socket=tmp_path / "fast.sock", **common)
    for run in (virtual, paced, unreachable):
        assert run.exit_code == 0 and run.summary["overruns"] == 0 and run.summary["ticks"] == 750
    assert 0.0 < paced.summary["achieved_speed"] <= 20.5
    assert 0.0 < unreachable.summary["achieved_speed"] < 1e5
    for run in (paced, unreachable):
        assert run.summary["ptc_periodic_amplitude_K"] == pytest.approx(virtual.summary["ptc_periodic_amplitude_K"],
                                                                        rel=0.1)
        assert run.summary["rms_K"] == pytest.approx(virtual.summary["rms_K"], rel=0.1)
    assert paced.summary["record_path"] == str(paced.log_paths[-1])
