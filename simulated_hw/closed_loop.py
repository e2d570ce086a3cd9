"""The simulated cryostat under PI control or a programmed heater, without instruments.

For control studies (docs/control.md) and for making test records: each
80 ms period the flange thermometer is read (with sensor noise), the heater
power is chosen (a programmed power, or the PI controller with its setpoint
ramp) and held until the next period. The daemon runs the same controller
against simulated instruments; this is the fast path for many runs.

Examples
--------
>>> from cryod.model import load_model
>>> from cryod.control.pi import PiGains
>>> run = run_program(load_model(), [Segment(0.0, setpoint_K=5.0)], duration_s=600.0,
...                   gains=PiGains(0.5, 0.01), heater_max_w=0.5, seed=1)
>>> abs(float(run.flange_K[-1]) - 5.0) < 0.01
True
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from cryod.control.pi import PiController, PiGains, SetpointRamp
from cryod.model import CryostatModel, CryostatPlant


@dataclass(frozen=True)
class Segment:
    """From ``start_s`` on: PI to ``setpoint_K``, or the heater at ``heater_power_w``.

    ``heater_power_w`` may be a number (W) or a function of time (s) giving W,
    for steps and modulation; exactly one of the two must be given.
    """

    start_s: float
    setpoint_K: float | None = None
    heater_power_w: float | Callable[[float], float] | None = None

    def __post_init__(self):
        if (self.setpoint_K is None) == (self.heater_power_w is None):
            raise ValueError("a segment has either a setpoint or a heater power, not both or neither")


@dataclass(frozen=True)
class ClosedLoopRun:
    """What a run recorded, one entry per period (the cryod-log columns)."""

    time_s: np.ndarray
    flange_K: np.ndarray
    ptc_stage_K: np.ndarray
    heater_w: np.ndarray
    setpoint_K: np.ndarray          # NaN where the loop is open
    proportional_w: np.ndarray
    integral_w: np.ndarray

    def columns(self) -> dict:
        """Columns for :func:`cryod.record.write_record`."""
        return {"time_s": self.time_s, "T2_K": self.flange_K, "T5_K": self.ptc_stage_K,
                "heater_W": self.heater_w, "setpoint_K": self.setpoint_K,
                "pi_proportional_W": self.proportional_w, "pi_integral_W": self.integral_w}


def run_program(model: CryostatModel, segments: Sequence[Segment], duration_s: float, *,
                gains: PiGains, heater_max_w: float, period_s: float = 0.08,
                ramp_K_per_min: float = 0.0, seed: int | None = 0, noise: bool = True,
                initial_heater_power_w: float = 0.0,
                current_output_resistance_ohm: float | None = None,
                unrecorded_heat_w: Callable[[float], float] | None = None,
                timing_jitter_s: float = 0.0) -> ClosedLoopRun:
    """Run a program of segments on the simulated cryostat.

    Parameters
    ----------
    model : CryostatModel
    segments : sequence of Segment
        In time order; the first should start at 0.
    duration_s : float
        Length of the run (s).
    gains : PiGains
    heater_max_w : float
        Heater power limit, R * I_max**2 (W).
    period_s : float
        Loop period (s).
    ramp_K_per_min : float
        Setpoint ramp rate (0: steps).
    seed : int, optional
        Sensor-noise seed.
    noise : bool
        Add sensor noise to what the controller sees and what is recorded.
    initial_heater_power_w : float
        Power the cryostat has settled at before the start.
    current_output_resistance_ohm : float, optional
        Study a controller whose output is the heater current instead: the
        gains are then in A/K and A/(K s), the output is held within
        0..sqrt(heater_max_w / R) A and the power is R I**2 (cryod's own PI
        outputs power; this is for comparing with controllers that do not).
    unrecorded_heat_w : callable, optional
        Extra heat (W) reaching the heater's paths at time t (s) that the
        record does not show: a disturbance (a heat leak) for testing the
        analysis. The recorded ``heater_w`` stays the commanded power.

    Returns
    -------
    ClosedLoopRun
    """
    segments = sorted(segments, key=lambda s: s.start_s)
    ticks = int(round(duration_s / period_s))
    plant = CryostatPlant(model, 0.0, initial_heater_power_w)
    resistance = current_output_resistance_ohm
    output_max = heater_max_w if resistance is None else float(np.sqrt(heater_max_w / resistance))

    def to_power(output: float) -> float:
        return output if resistance is None else resistance * output * output

    def to_output(power: float) -> float:
        return power if resistance is None else float(np.sqrt(power / resistance))

    controller = PiController(gains, 0.0, output_max)
    controller.set_manual(to_output(min(initial_heater_power_w, heater_max_w)))
    ramp = SetpointRamp(model.operating_point.flange_temperature_K, ramp_K_per_min)
    generator = np.random.default_rng(seed)
    noise_flange = model.sensor_noise.flange_thermometer_rms_K if noise else 0.0
    noise_stage = model.sensor_noise.ptc_stage_thermometer_rms_K if noise else 0.0
    out = {name: np.empty(ticks) for name in ("t", "T2", "T5", "P", "sp", "p", "i")}
    starts = [s.start_s for s in segments]
    lateness = generator.uniform(0.0, timing_jitter_s, ticks) if timing_jitter_s > 0.0 else np.zeros(ticks)
    for tick in range(ticks):
        now = tick * period_s + float(lateness[tick])
        plant.advance_to(now)
        flange, stage = plant.temperatures()
        flange += noise_flange * generator.standard_normal()
        stage += noise_stage * generator.standard_normal()
        index = int(np.searchsorted(starts, now + 1e-9, side="right")) - 1
        segment = segments[max(index, 0)]
        if segment.setpoint_K is not None:
            ramp.target_K = segment.setpoint_K
            if controller.is_manual:
                # bumpless against the present temperature; the setpoint step then acts through Kp
                ramp.setpoint_K = flange if ramp_K_per_min > 0.0 else segment.setpoint_K
                controller.set_automatic(flange, flange)
            setpoint = ramp.advance(period_s)
            requested = controller.update(flange, setpoint, period_s)
            output = min(max(requested, 0.0), output_max)
            controller.limit(requested, output)
            power = to_power(output)
        else:
            program = segment.heater_power_w
            power = float(program(now) if callable(program) else program)
            if not 0.0 <= power <= heater_max_w:
                raise ValueError(f"programmed heater power {power} W at {now:.2f} s is outside 0..{heater_max_w} W")
            controller.set_manual(to_output(power))
            setpoint = np.nan
        plant.set_heater_power(power + (unrecorded_heat_w(now) if unrecorded_heat_w else 0.0), now)
        for name, value in zip(out, (now, flange, stage, power, setpoint,
                                      controller.proportional_w if not controller.is_manual else np.nan,
                                      controller.integral_w if not controller.is_manual else np.nan)):
            out[name][tick] = value
    return ClosedLoopRun(out["t"], out["T2"], out["T5"], out["P"], out["sp"], out["p"], out["i"])
