"""The paper's Table 1 experiments run on a model, for comparing a model with the measurements.

``step_responses``: the 8.8 mW heater step on T2 and T5; ``open_loop_line``: the cooler's line on
T2 and T5 with the heater off, and T2's lag behind T5.
"""

import numpy as np

from cryod.analysis import paper_table1 as table1
from cryod.cooler.line_fit import fit_line, wrap_phase
from cryod.model import simulate

PERIOD = 0.08


def step_responses(model, duration_s=2500.0):
    """Response to the 8.8 mW step: difference of runs with and without it (the PTC line cancels)."""
    times = np.arange(0.0, duration_s, PERIOD)
    step = simulate(model, times, np.full(times.size, table1.STEP_POWER_W), initial_heater_power_w=0.0)
    still = simulate(model, times, np.zeros(times.size))
    return times, step.flange_K - still.flange_K, step.ptc_stage_K - still.ptc_stage_K


def open_loop_line(model):
    """The line's amplitude on T2 and on T5 (K) and T2's lag behind T5 (rad), heater off for 600 s."""
    times = np.arange(0.0, 600.0, PERIOD)
    record = simulate(model, times, np.zeros(times.size))
    omega = table1.LINE_ANGULAR_FREQUENCY_RAD_S
    flange = fit_line(times, record.flange_K, omega)
    stage = fit_line(times, record.ptc_stage_K, omega)
    return flange.amplitude[0], stage.amplitude[0], wrap_phase(stage.phase_rad[0] - flange.phase_rad[0])
