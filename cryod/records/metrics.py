"""Regulation figures of merit over a window of rows (``cryod --simulate --json``).

* ``ptc_line_amplitude_K``: amplitude of T2 at the PTC frequency (least-squares
  fit at one frequency: ``ptc_line_rad_s``, the cooler's frequency as the daemon
  tracks it on T5, where the line is 70 times larger,
  :func:`cryod.cooler.phase.cooler_frequency_rad_s`);
* ``ptc_periodic_amplitude_K``: T2's whole part synchronous with the cooler,
  harmonics 1 to 6 against the cooler's phase tracked from T5 sample by sample
  (:mod:`cryod.cooler.periodic`), as sqrt(2) times its rms (the square
  root of the sum of the harmonics' squared amplitudes); unlike the line at one
  frequency it stays true when the cooler's frequency wanders;
  ``ptc_harmonic_amplitudes_K``: the harmonics' amplitudes;
* ``mean_error_K``, ``rms_K``: mean and rms of T2 minus the setpoint;
* ``lowfreq_rms_K``: rms of T2 minus the setpoint below 0.1 Hz (zero-phase
  4th-order Butterworth low-pass), what drifts slower than 10 s; over the
  window less its first and last :data:`LOW_FREQUENCY_EDGE_S` (where the
  filter starts and ends, the line of a millikelvin leaves transients of tens
  of microkelvin that are not T2's), in windows long enough for that.

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 300.0, 0.08)
>>> m = regulation_metrics(t, 5.0 + 0.0015 * np.sin(10.83 * t), 3.3 + 0.12 * np.sin(10.83 * t + 1.1),
...                        np.full(t.size, 5.0), 10.83)
>>> round(m["ptc_line_amplitude_K"], 6), round(m["rms_K"], 6), m["lowfreq_rms_K"] < 1e-5
(0.0015, 0.001061, True)
"""

from __future__ import annotations

import numpy as np

from cryod.cooler.line_fit import fit_line
from cryod.cooler.periodic import PERIODIC_HARMONICS, periodic_amplitudes
from cryod.cooler.phase import cooler_frequency_rad_s

LOW_FREQUENCY_HZ = 0.1
#: The low-pass's start and end transients are left out of ``lowfreq_rms_K`` this long (s) ...
LOW_FREQUENCY_EDGE_S = 30.0
#: ... in windows at least this long (s).
LOW_FREQUENCY_MIN_WINDOW_S = 120.0


def regulation_metrics(time_s, flange_K, ptc_stage_K, setpoint_K, nominal_line_rad_s: float,
                       ptc_stage_time_s=None, lead_in_s: float = 0.0) -> dict:
    """Figures of merit of T2 against the setpoint over the rows given.

    Parameters
    ----------
    time_s, flange_K, ptc_stage_K, setpoint_K : array_like
        Instants of the T2 readings (s), T2 and T5 (K), setpoint (K; NaN where the loop was open).
    nominal_line_rad_s : float
        Expected PTC angular frequency (rad/s).
    ptc_stage_time_s : array_like, optional
        Instants of the T5 readings where they differ from T2's (s).
    lead_in_s : float
        The first rows, this long, only let the phase tracker lock; the
        figures are over the rest.

    Returns
    -------
    dict
        ``ptc_line_amplitude_K``, ``ptc_line_rad_s``, ``ptc_periodic_amplitude_K``,
        ``ptc_harmonic_amplitudes_K``, ``mean_error_K``, ``rms_K``, ``lowfreq_rms_K``,
        ``window_s`` (NaN entries where there is no setpoint).
    """
    time_s = np.asarray(time_s, dtype=float)
    stage_time_s = time_s if ptc_stage_time_s is None else np.asarray(ptc_stage_time_s, dtype=float)
    flange_K = np.asarray(flange_K, dtype=float)
    ptc_stage_K = np.asarray(ptc_stage_K, dtype=float)
    setpoint_K = np.asarray(setpoint_K, dtype=float)
    valid = np.isfinite(flange_K) & np.isfinite(ptc_stage_K) & np.isfinite(time_s) & np.isfinite(stage_time_s)
    time_s, flange_K, ptc_stage_K, setpoint_K = time_s[valid], flange_K[valid], ptc_stage_K[valid], setpoint_K[valid]
    stage_time_s = stage_time_s[valid]
    nan = float("nan")
    result = {"window_s": 0.0, "ptc_line_amplitude_K": nan, "ptc_line_rad_s": nan,
              "ptc_periodic_amplitude_K": nan, "ptc_harmonic_amplitudes_K": [nan] * PERIODIC_HARMONICS,
              "mean_error_K": nan, "rms_K": nan, "lowfreq_rms_K": nan}
    if time_s.size < 50:
        return result
    window_start = time_s[0] + lead_in_s
    harmonics = periodic_amplitudes(time_s, flange_K, stage_time_s, ptc_stage_K, nominal_line_rad_s,
                                    window_start_s=window_start)
    result["ptc_harmonic_amplitudes_K"] = [float(a) for a in harmonics]
    result["ptc_periodic_amplitude_K"] = float(np.sqrt(np.sum(harmonics ** 2)))
    inside = time_s >= window_start
    time_s, flange_K, ptc_stage_K, setpoint_K = time_s[inside], flange_K[inside], ptc_stage_K[inside], \
        setpoint_K[inside]
    stage_time_s = stage_time_s[inside]
    result["window_s"] = float(time_s[-1] - time_s[0]) if time_s.size else 0.0
    if time_s.size < 50:
        return result
    omega = cooler_frequency_rad_s(stage_time_s, ptc_stage_K, nominal_line_rad_s)    # as the daemon tracks it
    omega = omega if np.isfinite(omega) else nominal_line_rad_s
    result["ptc_line_rad_s"] = omega
    result["ptc_line_amplitude_K"] = fit_line(time_s, flange_K, omega).amplitude[0]
    regulated = np.isfinite(setpoint_K)
    if regulated.sum() >= 50:
        error = flange_K[regulated] - setpoint_K[regulated]
        result["mean_error_K"] = float(np.mean(error))
        result["rms_K"] = float(np.sqrt(np.mean(error ** 2)))
        sample_rate = 1.0 / float(np.median(np.diff(time_s[regulated])))
        from scipy import signal  # here: scipy.signal takes a second to import, and only this needs it

        sos = signal.butter(4, LOW_FREQUENCY_HZ, btype="low", fs=sample_rate, output="sos")
        if error.size > 3 * 2 * sos.shape[0] + 1:
            slow = signal.sosfiltfilt(sos, error)
            instants = time_s[regulated]
            if instants[-1] - instants[0] >= LOW_FREQUENCY_MIN_WINDOW_S:
                slow = slow[(instants >= instants[0] + LOW_FREQUENCY_EDGE_S)
                            & (instants <= instants[-1] - LOW_FREQUENCY_EDGE_S)]
            result["lowfreq_rms_K"] = float(np.sqrt(np.mean(slow ** 2)))
    return result
