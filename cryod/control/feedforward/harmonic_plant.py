"""The cryostat at the cooler's harmonics, as the 80 ms loop sees it: heater to T2's readings, and the line.

Both are functions of the phase the feedforward tracks (T5's fundamental is
``A cos(phase)``), and both are what the loop's readings contain: the heater's
settings are held between ticks and T2 is read once per tick, so above half the
sampling rate the hold's images fold back onto each harmonic
(:meth:`~cryod.model.transfer_function.TransferFunction.sampled_response`).
The feedforward (:mod:`cryod.control.feedforward`) learns on them and the
physical limit (:mod:`cryod.control.feedforward.limit`) optimises with them.

Examples
--------
>>> import numpy as np
>>> from cryod.model import load_model
>>> model = load_model()
>>> round(float(abs(line_at_harmonics(model, 1)[0])) * 1e3, 3)    # T2's line, mK
1.73
>>> round(float(abs(plant_at_harmonics(model, [1], 0.08)[0])) * 1e3, 2)   # mK/W through the hold
7.36
"""

from __future__ import annotations

import cmath

import numpy as np

from cryod.model import CryostatModel
from cryod.model.cooler_path import CoolerDrive, CoolerPath
from cryod.model.dynamics import flange_transfer_functions, stage_transfer_functions


def plant_at_harmonics(model: CryostatModel, orders, period_s: float, setting_delay_s: float = 0.0) -> np.ndarray:
    """From the waveform's coefficients to T2's samples at each harmonic of the cooler (K/W, complex).

    The loop samples T2, sets the heater ``setting_delay_s`` later to the
    waveform's value at the middle of the coming hold, and holds it for a
    period: :meth:`~cryod.model.transfer_function.TransferFunction.sampled_response`
    of the heater-to-T2 path, with the phase of the hold's middle. Above half
    the sampling rate (the 4th harmonic and up at 80 ms) the hold's folded
    images make it differ much from ``G(j n omega)``.
    """
    heater, _ = flange_transfer_functions(model)
    omega = model.ptc.angular_frequency_rad_s * np.asarray(orders, dtype=float)
    middle = np.exp(1j * omega * (setting_delay_s + 0.5 * period_s))
    return heater.sampled_response(omega, period_s, setting_delay_s) * middle


def line_at_harmonics(model: CryostatModel, harmonics: int, time_scale: float = 1.0) -> np.ndarray:
    """The model's cooler line on T2 at each harmonic (K, complex), relative to the phase of
    T5's fundamental (the tracked phase: T5's fundamental is ``A cos(phase)``).

    ``time_scale`` multiplies the flange's time constants (the heat-capacity effect at a setpoint).
    """
    drive = CoolerDrive(model)
    omega = model.ptc.angular_frequency_rad_s
    flange = CoolerPath(drive, flange_transfer_functions(model)[1], input_is_heat=True)
    stage = CoolerPath(drive, stage_transfer_functions(model)[1], input_is_heat=False)
    rotations = [cmath.exp(1j * component.phase_rad) for component in drive.components]
    flange_phasors = [p * r for p, r in zip(flange.output_phasors(omega, time_scale), rotations)]
    stage_fundamental = next(p * r for p, r, c in zip(stage.output_phasors(omega), rotations, drive.components)
                             if c.order == 1)
    reference = cmath.phase(stage_fundamental)
    line = np.zeros(harmonics, dtype=complex)
    for component, phasor in zip(drive.components, flange_phasors):
        if component.order <= harmonics:
            line[component.order - 1] += phasor * cmath.exp(-1j * component.order * reference)
    return line
