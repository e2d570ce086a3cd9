"""T2's part synchronous with the pulse-tube cooler.

:func:`periodic_amplitudes`: T2's harmonics 1 to 6 against the cooler's phase
tracked from T5 sample by sample (:mod:`cryod.cooler.phase`); their root sum
of squares is the ``ptc_periodic_amplitude_K`` of the records' metrics. Unlike
the line at one frequency it stays true when the cooler's frequency wanders.
The cooler's frequency itself, as the daemon tracks it: :func:`cryod.cooler.phase.cooler_frequency_rad_s`.

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 300.0, 0.08)
>>> stage = 3.3 + 0.12 * np.sin(10.83 * t + 1.1)
>>> amplitudes = periodic_amplitudes(t, 5.0 + 0.0015 * np.sin(10.83 * t), t, stage, 10.83, window_start_s=60.0)
>>> round(float(amplitudes[0]), 5), bool(amplitudes[1:].max() < 1e-6)
(0.0015, True)
"""

from __future__ import annotations

import numpy as np

from cryod.cooler.phase import track_cooler_phase

#: Harmonics of the cooler in the periodic amplitude.
PERIODIC_HARMONICS = 6
#: Degree of the polynomial that takes the slow part out of T2 before the periodic fit.
SLOW_DEGREE = 3


def periodic_amplitudes(flange_time_s, flange_K, stage_time_s, ptc_stage_K, nominal_rad_s: float,
                        harmonics: int = PERIODIC_HARMONICS, window_start_s: float = -np.inf) -> np.ndarray:
    """Amplitudes (K) of T2's harmonics 1..``harmonics`` of the cooler, phase tracked from T5.

    The tracker runs over every reading given (those before ``window_start_s``
    only let it lock); the least-squares fit of T2 (harmonics, and a cubic
    for the slow part) uses the readings from ``window_start_s`` on.
    """
    flange_time_s = np.asarray(flange_time_s, dtype=float)
    track = track_cooler_phase(stage_time_s, ptc_stage_K, nominal_rad_s)
    phase = track["phase_rad"] + track["frequency_rad_s"] * (flange_time_s - np.asarray(stage_time_s, float))
    use = (flange_time_s >= window_start_s) & track["locked"]
    if use.sum() < 4 * harmonics + 10:
        return np.full(harmonics, np.nan)
    t = flange_time_s[use]
    scaled = (t - t.mean()) / max(float(np.ptp(t)), 1e-9)
    angles = np.outer(phase[use], np.arange(1, harmonics + 1))
    columns = np.hstack([np.vander(scaled, SLOW_DEGREE + 1), np.cos(angles), np.sin(angles)])
    solution, *_ = np.linalg.lstsq(columns, np.asarray(flange_K, float)[use], rcond=None)
    cosines = solution[SLOW_DEGREE + 1:SLOW_DEGREE + 1 + harmonics]
    sines = solution[SLOW_DEGREE + 1 + harmonics:]
    return np.hypot(cosines, sines)
