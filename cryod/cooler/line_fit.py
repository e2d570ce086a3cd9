"""Amplitude and phase of the PTC line (and its harmonics) in a sampled record.

A least-squares fit of ``offset + trend + sum_k A_k sin(k omega t + phi_k)``:
unlike an FFT bin, it needs neither a whole number of periods nor uniform
sampling, and it gives the amplitude directly in K.

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 60.0, 0.08)
>>> fit = fit_line(t, 4.26 + 0.0017 * np.sin(10.83 * t + 1.89), 10.83)
>>> round(fit.amplitude[0], 6), round(fit.phase_rad[0], 3)
(0.0017, 1.89)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LineFit:
    """Result of :func:`fit_line`.

    Attributes
    ----------
    angular_frequency_rad_s : float
        Fundamental angular frequency used.
    orders : tuple of int
        Harmonic orders fitted (1 is the fundamental).
    amplitude : tuple of float
        Amplitude of each order, in the units of the data.
    phase_rad : tuple of float
        Phase of each order in ``sin(k omega t + phase)``, wrapped to (-pi, pi].
    offset : float
        Mean level at ``t = 0`` of the fitted time axis.
    residual_rms : float
        Rms of what the fit leaves.
    amplitude_uncertainty : tuple of float
        Standard error of each amplitude (white residual assumed).
    """

    angular_frequency_rad_s: float
    orders: tuple[int, ...]
    amplitude: tuple[float, ...]
    phase_rad: tuple[float, ...]
    offset: float
    residual_rms: float
    amplitude_uncertainty: tuple[float, ...]


def wrap_phase(phase_rad):
    """Wrap phases to (-pi, pi]."""
    wrapped = np.mod(np.asarray(phase_rad, dtype=float) + math.pi, 2.0 * math.pi) - math.pi
    wrapped = np.where(wrapped == -math.pi, math.pi, wrapped)
    return float(wrapped) if np.ndim(wrapped) == 0 else wrapped


def fit_line(time_s, values, angular_frequency_rad_s: float, orders=(1,), trend_order: int = 1) -> LineFit:
    """Fit a line and its harmonics by linear least squares.

    Parameters
    ----------
    time_s, values : array_like
        Sample instants (s) and the signal.
    angular_frequency_rad_s : float
        Fundamental angular frequency (rad/s).
    orders : sequence of int or int
        Harmonic orders to fit; an int n means ``1..n``.
    trend_order : int
        Degree of the polynomial baseline fitted alongside (0: constant).

    Returns
    -------
    LineFit
    """
    time_s = np.asarray(time_s, dtype=float)
    values = np.asarray(values, dtype=float)
    if isinstance(orders, int):
        orders = tuple(range(1, orders + 1))
    orders = tuple(int(k) for k in orders)
    centre = 0.5 * (time_s[0] + time_s[-1])
    span = max(0.5 * (time_s[-1] - time_s[0]), 1e-12)
    columns = [((time_s - centre) / span) ** p for p in range(trend_order + 1)]
    for k in orders:
        columns.append(np.sin(k * angular_frequency_rad_s * time_s))
        columns.append(np.cos(k * angular_frequency_rad_s * time_s))
    design = np.column_stack(columns)
    solution, *_ = np.linalg.lstsq(design, values, rcond=None)
    residual = values - design @ solution
    dof = max(values.size - design.shape[1], 1)
    residual_rms = float(np.sqrt(np.sum(residual ** 2) / dof))
    base = trend_order + 1
    amplitudes, phases, errors = [], [], []
    # standard error of a sine/cosine coefficient for white residual
    try:
        covariance = np.linalg.inv(design.T @ design) * residual_rms ** 2
    except np.linalg.LinAlgError:
        covariance = np.full((design.shape[1],) * 2, np.nan)
    for index in range(len(orders)):
        s_coef = solution[base + 2 * index]
        c_coef = solution[base + 2 * index + 1]
        amplitude = math.hypot(s_coef, c_coef)
        amplitudes.append(amplitude)
        phases.append(wrap_phase(math.atan2(c_coef, s_coef)))
        variance = 0.5 * (covariance[base + 2 * index, base + 2 * index]
                          + covariance[base + 2 * index + 1, base + 2 * index + 1])
        errors.append(float(math.sqrt(max(variance, 0.0))))
    offset = float(sum(solution[p] * ((time_s[0] - centre) / span) ** p for p in range(base)))
    return LineFit(
        angular_frequency_rad_s=float(angular_frequency_rad_s),
        orders=orders,
        amplitude=tuple(amplitudes),
        phase_rad=tuple(phases),
        offset=offset,
        residual_rms=residual_rms,
        amplitude_uncertainty=tuple(errors),
    )
