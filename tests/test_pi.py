import numpy as np
import pytest

from cryod.control.pi import PiController, PiGains
from cryod.control.ramp import SetpointRamp
from cryod.control.regulator import ControlConfig, HeaterPowerOutput, Regulator
from cryod.control.closed_loop import Segment, run_program


def control_section(gains: PiGains, setpoint_K: float | None = None) -> ControlConfig:
    return ControlConfig(setpoint_K=setpoint_K, ramp_K_per_min=0.0, setpoint_min_K=1.0, setpoint_max_K=20.0,
                         max_ramp_K_per_min=10.0, terms=(("pi", gains),))


def test_proportional_and_integral_parts():
    pi = PiController(PiGains(2.0, 0.5), 0.0, 10.0)
    out = pi.update(measured_K=4.0, setpoint_K=5.0, dt_s=0.1)
    assert pi.proportional_w == pytest.approx(2.0)
    assert pi.integral_w == pytest.approx(0.05)
    assert out == pytest.approx(2.05)


def test_anti_windup_stops_integrating_into_a_held_limit():
    pi = PiController(PiGains(1.0, 1.0), 0.0, 0.5)
    for _ in range(100):
        requested = pi.update(measured_K=4.0, setpoint_K=5.0, dt_s=0.1)
        pi.limit(requested, min(requested, 0.5))
    assert pi.integral_w == pytest.approx(0.0)          # never grew while the heater was held at 0.5 W
    requested = pi.update(measured_K=5.2, setpoint_K=5.0, dt_s=0.1)   # overshoot: comes off the limit at once
    assert requested < 0.0 + 1e-12


def test_gain_change_and_auto_manual_transfer_are_bumpless():
    regulator = Regulator(control_section(PiGains(1.0, 0.1), setpoint_K=5.0), HeaterPowerOutput(1.0))
    regulator.set_manual(0.3)
    assert regulator.step(0.0, 0.08, 4.0, 3.3).power_w == 0.3
    # closing the loop continues from the 0.3 W that was applied; the setpoint step acts through Kp
    regulator.close_loop(0.08, flange_K=4.9, ptc_stage_K=3.3, present_power_w=0.3)
    assert regulator.terms[0].controller.output_w == pytest.approx(0.3)
    assert regulator.step(0.16, 0.08, 4.9, 3.3).power_w == pytest.approx(0.3 + 1.0 * 0.1 + 0.1 * 0.1 * 0.08)
    pi = PiController(PiGains(1.0, 0.1), 0.0, 1.0)
    pi.set_automatic(measured_K=4.9, setpoint_K=5.0, present_power_w=0.3)
    assert pi.output_w == pytest.approx(0.3)
    first = pi.update(4.9, 5.0, 0.08)
    assert first == pytest.approx(0.3 + 0.1 * 0.1 * 0.08)
    pi.set_gains(PiGains(3.0, 0.1))
    assert pi.proportional_w + pi.integral_w == pytest.approx(first)


def test_refuses_bad_gains_and_manual_power_outside_range():
    with pytest.raises(ValueError, match="proportional"):
        PiGains(-1.0, 0.1)
    with pytest.raises(ValueError, match="outside"):
        Regulator(control_section(PiGains(1.0, 0.1)), HeaterPowerOutput(0.5)).set_manual(0.6)


def test_setpoint_ramp_rate():
    ramp = SetpointRamp(4.23, rate_K_per_min=0.5)
    ramp.target_K = 5.0
    values = [ramp.advance(0.08) for _ in range(1500)]
    assert values[749] == pytest.approx(4.23 + 0.5 / 60 * 0.08 * 750)
    assert values[-1] == 5.0 and not ramp.ramping
    down = SetpointRamp(5.0)
    down.target_K = 4.5
    assert down.advance(0.08) == 4.5


def test_closed_loop_reaches_setpoint_and_holds_heater_range(reference_model):
    run = run_program(reference_model, [Segment(0.0, setpoint_K=5.0)], 900.0,
                      gains=PiGains(0.4, 0.01), heater_max_w=0.25, seed=3)
    late = run.time_s > 600
    assert np.mean(run.flange_K[late]) == pytest.approx(5.0, abs=2e-4)
    assert np.all((run.heater_w >= 0.0) & (run.heater_w <= 0.25))
    # mean heater power at 5 K is set by the thermal balance: (5 - 4.23) / 6.818 K/W
    assert np.mean(run.heater_w[late]) == pytest.approx(0.77 / 6.8182, rel=0.01)


def test_programmed_heater_outside_range_is_refused(reference_model):
    with pytest.raises(ValueError, match="outside"):
        run_program(reference_model, [Segment(0.0, heater_power_w=0.3)], 1.0,
                    gains=PiGains(0.4, 0.01), heater_max_w=0.25)


def test_gain_change_stays_bumpless_when_the_integral_must_go_negative():
    """A large error and a doubled Kp: the integral has to offset more than it holds."""
    pi = PiController(PiGains(10.0, 0.2), 0.0, 0.5)
    pi.set_automatic(measured_K=4.978, setpoint_K=5.0, present_power_w=0.235)
    before = pi.output_w
    pi.set_gains(PiGains(20.0, 0.4))
    assert pi.integral_w < 0.0
    assert pi.proportional_w + pi.integral_w == pytest.approx(before)


def test_integral_from_a_transfer_is_not_pulled_back_at_once():
    pi = PiController(PiGains(20.0, 0.4), 0.0, 0.5)
    pi.set_automatic(measured_K=4.9, setpoint_K=5.0, present_power_w=0.3)
    pi.set_gains(PiGains(40.0, 0.4))         # integral must become 0.3 - 4.0 = -3.7 W
    assert pi.integral_w == pytest.approx(-3.7)
    pi.update(measured_K=4.9, setpoint_K=5.0, dt_s=0.08)
    assert pi.integral_w == pytest.approx(-3.7 + 0.4 * 0.1 * 0.08)   # integrates from there, no jump to -0.5
    assert pi.output_w == pytest.approx(0.3 + 0.4 * 0.1 * 0.08)
