"""Regulation figures of merit over a window of rows (``cryod --simulate --json``).

* ``ptc_line_amplitude_K``: amplitude of T2 at the PTC frequency (least-squares
  fit; the frequency is refined on T5, where the line is 70 times larger);
* ``mean_error_K``, ``rms_K``: mean and rms of T2 minus the setpoint;
* ``lowfreq_rms_K``: rms of T2 minus the setpoint below 0.1 Hz (zero-phase
  4th-order Butterworth low-pass), what drifts slower than 10 s.

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
from scipy import optimize, signal

from cryod.analysis.line_fit import fit_line

LOW_FREQUENCY_HZ = 0.1


def line_frequency(time_s: np.ndarray, ptc_stage_K: np.ndarray, nominal_rad_s: float,
                   search_rad_s: float = 0.2) -> float:
    """The PTC angular frequency (rad/s) that maximises the line on T5 near ``nominal_rad_s``."""
    result = optimize.minimize_scalar(
        lambda omega: -fit_line(time_s, ptc_stage_K, omega, trend_order=0).amplitude[0],
        bounds=(nominal_rad_s - search_rad_s, nominal_rad_s + search_rad_s), method="bounded",
        options={"xatol": 1e-6})
    return float(result.x)


def regulation_metrics(time_s, flange_K, ptc_stage_K, setpoint_K, nominal_line_rad_s: float,
                       ptc_stage_time_s=None) -> dict:
    """Figures of merit of T2 against the setpoint over the rows given.

    Parameters
    ----------
    time_s, flange_K, ptc_stage_K, setpoint_K : array_like
        Instants of the T2 readings (s), T2 and T5 (K), setpoint (K; NaN where the loop was open).
    nominal_line_rad_s : float
        Expected PTC angular frequency (rad/s).
    ptc_stage_time_s : array_like, optional
        Instants of the T5 readings where they differ from T2's (s).

    Returns
    -------
    dict
        ``ptc_line_amplitude_K``, ``ptc_line_rad_s``, ``mean_error_K``, ``rms_K``,
        ``lowfreq_rms_K``, ``window_s`` (NaN entries where there is no setpoint).
    """
    time_s = np.asarray(time_s, dtype=float)
    stage_time_s = time_s if ptc_stage_time_s is None else np.asarray(ptc_stage_time_s, dtype=float)
    flange_K = np.asarray(flange_K, dtype=float)
    ptc_stage_K = np.asarray(ptc_stage_K, dtype=float)
    setpoint_K = np.asarray(setpoint_K, dtype=float)
    valid = np.isfinite(flange_K) & np.isfinite(ptc_stage_K) & np.isfinite(time_s) & np.isfinite(stage_time_s)
    time_s, flange_K, ptc_stage_K, setpoint_K = time_s[valid], flange_K[valid], ptc_stage_K[valid], setpoint_K[valid]
    stage_time_s = stage_time_s[valid]
    result = {"window_s": float(time_s[-1] - time_s[0]) if time_s.size else 0.0,
              "ptc_line_amplitude_K": float("nan"), "ptc_line_rad_s": float("nan"),
              "mean_error_K": float("nan"), "rms_K": float("nan"), "lowfreq_rms_K": float("nan")}
    if time_s.size < 50:
        return result
    omega = line_frequency(stage_time_s, ptc_stage_K, nominal_line_rad_s)
    result["ptc_line_rad_s"] = omega
    result["ptc_line_amplitude_K"] = fit_line(time_s, flange_K, omega).amplitude[0]
    regulated = np.isfinite(setpoint_K)
    if regulated.sum() >= 50:
        error = flange_K[regulated] - setpoint_K[regulated]
        result["mean_error_K"] = float(np.mean(error))
        result["rms_K"] = float(np.sqrt(np.mean(error ** 2)))
        sample_rate = 1.0 / float(np.median(np.diff(time_s[regulated])))
        sos = signal.butter(4, LOW_FREQUENCY_HZ, btype="low", fs=sample_rate, output="sos")
        if error.size > 3 * 2 * sos.shape[0] + 1:
            result["lowfreq_rms_K"] = float(np.sqrt(np.mean(signal.sosfiltfilt(sos, error) ** 2)))
    return result
