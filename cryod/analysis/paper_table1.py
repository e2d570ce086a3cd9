"""The measurements of Pan et al., Part 1, Table 1, as functions of time.

These are the cryostat's measured responses (as the paper's fitted functions):
the model must reproduce them, and ``cryod analyze`` can be run on records
regenerated from them.

Examples
--------
>>> round(float(flange_step_response_K(1e6)), 4)
4.29
>>> round(float(ptc_stage_step_response_K(135.0)) - PTC_STAGE_START_K, 4)
0.0152
"""

from __future__ import annotations

import numpy as np

#: Heater step of the step-response experiment (W).
STEP_POWER_W = 0.0088
FLANGE_START_K = 4.23
#: Flange step response: amplitudes (K) and time constants (s) of the two exponentials.
FLANGE_STEP_TERMS = ((0.01, 26.48), (0.05, 165.41))
PTC_STAGE_START_K = 3.34
#: Table 1 prints -0.024 K; eq. (3) and the physics (heating loads the cooler) give +0.024 K.
PTC_STAGE_STEP_K = 0.024
PTC_STAGE_TIME_CONSTANT_S = 134.96

#: Open loop, heater off: mean levels (K), amplitudes (K), angular frequency (rad/s).
OPEN_LOOP_FLANGE_MEAN_K = 4.26
OPEN_LOOP_PTC_STAGE_MEAN_K = 3.33
FLANGE_LINE_AMPLITUDE_K = 0.00173
PTC_STAGE_LINE_AMPLITUDE_K = 0.12361
LINE_ANGULAR_FREQUENCY_RAD_S = 10.83
PTC_STAGE_LINE_PHASE_RAD = 3.02
#: T2 lags T5 by this much at the line (rad).
FLANGE_LAG_BEHIND_PTC_STAGE_RAD = 1.134


def flange_step_response_K(time_s):
    """T2 (K) after the 8.8 mW heater step at t = 0 (PTC line averaged out)."""
    time_s = np.clip(np.asarray(time_s, dtype=float), 0.0, None)
    rise = sum(amplitude * (1.0 - np.exp(-time_s / tau)) for amplitude, tau in FLANGE_STEP_TERMS)
    return FLANGE_START_K + rise


def ptc_stage_step_response_K(time_s):
    """T5 (K) after the 8.8 mW heater step at t = 0 (PTC line averaged out)."""
    time_s = np.clip(np.asarray(time_s, dtype=float), 0.0, None)
    return PTC_STAGE_START_K + PTC_STAGE_STEP_K * (1.0 - np.exp(-time_s / PTC_STAGE_TIME_CONSTANT_S))


def open_loop_flange_K(time_s):
    """T2 (K), open loop, heater off, with the line at the measured amplitude and lag."""
    time_s = np.asarray(time_s, dtype=float)
    phase = LINE_ANGULAR_FREQUENCY_RAD_S * time_s + PTC_STAGE_LINE_PHASE_RAD - FLANGE_LAG_BEHIND_PTC_STAGE_RAD
    return OPEN_LOOP_FLANGE_MEAN_K + FLANGE_LINE_AMPLITUDE_K * np.sin(phase)


def open_loop_ptc_stage_K(time_s):
    """T5 (K), open loop, heater off."""
    time_s = np.asarray(time_s, dtype=float)
    phase = LINE_ANGULAR_FREQUENCY_RAD_S * time_s + PTC_STAGE_LINE_PHASE_RAD
    return OPEN_LOOP_PTC_STAGE_MEAN_K + PTC_STAGE_LINE_AMPLITUDE_K * np.sin(phase)


def regenerated_record(duration_s: float = 1800.0, step_time_s: float = 300.0, sample_interval_s: float = 0.08,
                       flange_noise_rms_K: float = 20e-6, ptc_stage_noise_rms_K: float = 0.3e-3,
                       seed: int = 0) -> dict:
    """A cryod-log record regenerated from Table 1: the 8.8 mW step with the measured PTC line on top.

    The step response rows and the sinusoidal rows of Table 1 are superposed (the
    line's mean levels are those of the step rows), sampled every
    ``sample_interval_s`` and given white noise of the cryod model's default
    size. The heater is 0 W before ``step_time_s`` and 8.8 mW after.

    Returns
    -------
    dict
        Columns for :func:`cryod.records.record.write_record`.

    Examples
    --------
    >>> record = regenerated_record(duration_s=600.0, seed=1)
    >>> round(float(record["heater_W"][-1]), 4), len(record["T2_K"])
    (0.0088, 7500)
    """
    time_s = np.arange(0.0, duration_s, sample_interval_s)
    after = time_s - step_time_s
    generator = np.random.default_rng(seed)
    flange = (np.where(after >= 0.0, flange_step_response_K(after), FLANGE_START_K)
              + open_loop_flange_K(time_s) - OPEN_LOOP_FLANGE_MEAN_K)
    stage = (np.where(after >= 0.0, ptc_stage_step_response_K(after), PTC_STAGE_START_K)
             + open_loop_ptc_stage_K(time_s) - OPEN_LOOP_PTC_STAGE_MEAN_K)
    return {
        "time_s": time_s,
        "T2_K": flange + generator.normal(0.0, flange_noise_rms_K, time_s.size),
        "T5_K": stage + generator.normal(0.0, ptc_stage_noise_rms_K, time_s.size),
        "heater_W": np.where(time_s >= step_time_s, STEP_POWER_W, 0.0),
        "setpoint_K": np.full(time_s.size, np.nan),
    }
