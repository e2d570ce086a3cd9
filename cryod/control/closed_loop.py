"""The simulated cryostat under the regulator or a programmed heater, without instruments.

For control studies (docs/explanation/control.md) and for making test records: each
80 ms period the thermometers are read (with sensor noise), the heater power
is chosen (a programmed power, or the regulator of :mod:`cryod.control.regulator`,
the daemon's own control law, with its setpoint ramp) and held until the next
period. The daemon runs the same regulator against simulated instruments; this
is the fast path for many runs.

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

from cryod.control.pi import PiGains
from cryod.control.regulator import ControlConfig, HeaterCurrentOutput, HeaterPowerOutput, Regulator, RegulatorMode
from cryod.model import CryostatModel, cryostat_plant
from cryod.records.columns import REQUIRED


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
    control: dict                   # the control terms' columns by name (NaN where the loop is open)
    events: tuple = ()              # (time (s), term, logging level, text): what the terms said

    def columns(self) -> dict:
        """Columns for :func:`cryod.records.record.write_record`."""
        required = (self.time_s, self.flange_K, self.ptc_stage_K, self.heater_w, self.setpoint_K)
        return {**{column.name: values for column, values in zip(REQUIRED, required)}, **self.control}


def run_program(model: CryostatModel, segments: Sequence[Segment], duration_s: float, *,
                gains: PiGains, heater_max_w: float, period_s: float = 0.08,
                ramp_K_per_min: float = 0.0, seed: int | None = 0, noise: bool = True,
                initial_heater_power_w: float = 0.0,
                current_output_resistance_ohm: float | None = None,
                unrecorded_heat_w: Callable[[float], float] | None = None,
                timing_jitter_s: float = 0.0, more_terms: tuple = (), zones=None) -> ClosedLoopRun:
    """Run a program of segments on the simulated cryostat.

    Parameters
    ----------
    model : CryostatModel
    segments : sequence of Segment
        In time order; the first should start at 0.
    duration_s : float
        Length of the run (s).
    gains : PiGains
        Settings of the ``pi`` term.
    heater_max_w : float
        Heater power limit, R * I_max**2 (W).
    period_s : float
        Loop period (s).
    ramp_K_per_min : float
        Setpoint ramp rate (0: steps).
    seed : int, optional
        Sensor-noise seed.
    noise : bool
        Add sensor noise to what the regulator sees and what is recorded.
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
    timing_jitter_s : float
        Largest lateness of a reading after its period's start (s, uniform).
    more_terms : tuple of (name, settings)
        Control terms besides ``pi`` (names of :data:`cryod.control.terms.TERM_TYPES`).
    zones : cryod.control.zones.ZoneTable, optional
        A zone table (``control.zones``): each zone's settings replace ``gains`` and the terms' own
        while the setpoint in use is in it.

    Returns
    -------
    ClosedLoopRun
    """
    segments = sorted(segments, key=lambda s: s.start_s)
    ticks = int(round(duration_s / period_s))
    plant = cryostat_plant(model, 0.0, initial_heater_power_w)
    output = HeaterPowerOutput(heater_max_w) if current_output_resistance_ohm is None \
        else HeaterCurrentOutput(current_output_resistance_ohm, heater_max_w)
    control = ControlConfig(setpoint_K=None, ramp_K_per_min=ramp_K_per_min, setpoint_min_K=0.0,
                            setpoint_max_K=np.inf, max_ramp_K_per_min=np.inf, terms=(("pi", gains), *more_terms),
                            zones=zones)
    regulator = Regulator(control, output)
    power = min(initial_heater_power_w, heater_max_w)
    generator = np.random.default_rng(seed)
    noise_flange = model.sensor_noise.flange_thermometer_rms_K if noise else 0.0
    noise_stage = model.sensor_noise.ptc_stage_thermometer_rms_K if noise else 0.0
    recorded = np.empty((5, ticks))
    control_columns = {column.name: np.full(ticks, np.nan) for column in regulator.columns}
    starts = [s.start_s for s in segments]
    lateness = generator.uniform(0.0, timing_jitter_s, ticks) if timing_jitter_s > 0.0 else np.zeros(ticks)
    events = []
    for tick in range(ticks):
        now = tick * period_s + float(lateness[tick])
        plant.advance_to(now)
        flange, stage = plant.temperatures()
        flange += noise_flange * generator.standard_normal()
        stage += noise_stage * generator.standard_normal()
        index = int(np.searchsorted(starts, now + 1e-9, side="right")) - 1
        segment = segments[max(index, 0)]
        if segment.setpoint_K is not None:
            regulator.ramp.target_K = segment.setpoint_K
            if regulator.mode is not RegulatorMode.CLOSED:
                regulator.close_loop(now, flange, stage, present_power_w=power)
        else:
            program = segment.heater_power_w
            try:
                regulator.set_manual(float(program(now) if callable(program) else program))
            except ValueError as error:
                raise ValueError(f"programmed {error} at {now:.2f} s") from None
        step = regulator.step(now, period_s, flange, stage)
        power = step.power_w
        plant.set_heater_power(power + (unrecorded_heat_w(now) if unrecorded_heat_w else 0.0), now)
        recorded[:, tick] = now, flange, stage, power, step.setpoint_K
        for name, value in step.columns.items():
            try:
                control_columns[name][tick] = value
            except (TypeError, ValueError):         # a text column (or one empty for now): kept as objects
                control_columns[name] = control_columns[name].astype(object)
                control_columns[name][tick] = value
        events += [(now, *event) for event in step.events]
    regulator.close()
    return ClosedLoopRun(*recorded, control_columns, tuple(events))
