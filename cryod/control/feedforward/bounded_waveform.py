"""The best periodic waveform within bounds, when each harmonic acts on its own.

Why, and how well it works: docs/explanation/feedforward.md ("The physical limit").

A periodic input ``P(theta) = mean + Re sum_n a_n exp(j n theta)`` (n = 1..N) bounded by
``low <= P <= high``, with the mean fixed, moves harmonic n of an output by ``H_n a_n`` against a
disturbance ``L_n``. This module finds the waveform that leaves the least
``sum_n |L_n + H_n a_n|**2`` and a lower bound that no waveform, of any shape, beats. For the
cryostat, P is the heater power, L the cooler's line on T2 and H the heater's response
(:mod:`cryod.control.feedforward.limit`).

Conventions: ``a_n = (1/pi) int_0^2pi P(theta) exp(-j n theta) d theta`` (phasor amplitude: a
sinusoid ``A cos(n theta + p)`` has ``a_n = A exp(jp)``), arrays indexed from n = 1.

Examples
--------
A line of amplitude 1 that a unit-gain input cancels with an amplitude-1 sinusoid, when the
bounds leave room for it, and only partly when they do not:

>>> import numpy as np
>>> line, gain = np.array([1.0 + 0.0j]), np.array([1.0 + 0.0j])
>>> np.round(best_bounded_waveform(line, gain, mean=2.0, low=0.0, high=4.0), 6)
array([-1.+0.j])
>>> np.round(best_bounded_waveform(line, gain, mean=0.5, low=0.0, high=4.0), 3)
array([-0.5+0.j])
"""

from __future__ import annotations

import math

import numpy as np
from scipy import optimize

#: The bounds are checked on a grid this many times finer than the one they were imposed on.
FEASIBILITY_REFINEMENT = 8
#: Quadrature points of the lower bound's dual function.
BOUND_POINTS = 4096


def waveform_values(amplitudes: np.ndarray, mean: float, points: int) -> np.ndarray:
    """P at ``points`` equally spaced phases from 0: ``mean + Re sum_n a_n exp(j n theta)``.

    Examples
    --------
    >>> np.round(waveform_values(np.array([1.0, 0.0]), 2.0, 4), 6)
    array([3., 2., 1., 2.])
    """
    spectrum = np.zeros(points // 2 + 1, dtype=complex)
    spectrum[1:amplitudes.size + 1] = amplitudes
    return mean + np.fft.irfft(spectrum, points) * points / 2.0


def harmonic_amplitudes(values: np.ndarray, harmonics: int) -> np.ndarray:
    """``a_n = (1/pi) int P exp(-j n theta) d theta``, n = 1..harmonics, from equally spaced values."""
    return np.fft.rfft(values)[1:harmonics + 1] * 2.0 / values.size


def largest_fundamental(mean: float, low: float, high: float) -> float:
    """Largest |a_1| of any waveform within [low, high] with this mean.

    The maximiser is a rectangular pulse (``high`` over a fraction (mean - low) / (high - low) of
    the period, ``low`` elsewhere): ``(2 (high - low) / pi) sin(pi (mean - low) / (high - low))``.

    Examples
    --------
    >>> round(largest_fundamental(0.5, 0.0, 1.0), 4)     # a square wave: 2/pi
    0.6366
    """
    width = high - low
    if width <= 0.0:
        return 0.0
    return 2.0 * width / math.pi * math.sin(math.pi * min(max((mean - low) / width, 0.0), 1.0))


def best_bounded_waveform(line: np.ndarray, gain: np.ndarray, mean: float, low: float, high: float,
                          phase_points: int = 512, orders=None) -> np.ndarray:
    """Harmonic amplitudes a_n (n = 1..N) minimising ``sum |L_n + H_n a_n|**2`` within the bounds.

    Parameters
    ----------
    line : numpy.ndarray
        Complex L_n, n = 1..N (output units).
    gain : numpy.ndarray
        Complex H_n, none zero (output units per input unit).
    mean, low, high : float
        The waveform's fixed mean and its bounds (input units).
    phase_points : int
        Equally spaced phases at which the bounds are imposed (M > 2 max(orders)).
    orders : array of int, optional
        The harmonic each entry of ``line`` and ``gain`` is at (default 1..N); the waveform has no
        other harmonics.

    Returns
    -------
    numpy.ndarray
        Complex a_n, one per entry of ``line``. The waveform meets the bounds at the M phases and,
        after shrinking towards its mean if needed, on a grid ``FEASIBILITY_REFINEMENT`` times finer.

    Examples
    --------
    Harmonic 2 alone, when the bounds leave room for it:

    >>> second = best_bounded_waveform(np.array([0.5j]), np.array([1.0 + 0.0j]), 2.0, 0.0, 4.0, orders=[2])
    >>> round(float(abs(second[0])), 6), round(float(np.angle(second[0])), 4)
    (0.5, -1.5708)

    Notes
    -----
    A convex quadratic programme. With the residual ``r = L + H a`` as the variable
    (``a = (r - L) / H``) it is a least-distance problem, ``min |r|**2`` subject to linear
    inequalities, which :func:`scipy.optimize.nnls` solves exactly (Lawson and Hanson, *Solving
    Least Squares Problems*, 1974, ch. 23). Residual and input are scaled to order 1 first.
    """
    line = np.asarray(line, dtype=complex)
    gain = np.asarray(gain, dtype=complex)
    harmonics = line.size
    if not (low < mean < high):
        return np.zeros(harmonics, dtype=complex)       # the mean sits on a bound: no room to move
    output_scale = float(np.linalg.norm(line)) or 1.0
    input_scale = high - low
    orders = np.arange(1, harmonics + 1) if orders is None else np.asarray(orders, dtype=int)
    theta = 2.0 * math.pi * np.arange(phase_points) / phase_points
    rotor = np.exp(1j * np.outer(theta, orders))
    per_residual = rotor / gain * (output_scale / input_scale)                # dP / dr, scaled
    offset = (mean - (rotor @ (line / gain)).real - low) / input_scale        # P at r = 0, scaled
    slopes = np.hstack([per_residual.real, -per_residual.imag])
    # low <= P <= high as G x >= h: slopes x >= -offset, -slopes x >= offset - 1
    constraints = np.vstack([slopes, -slopes])
    limits = np.concatenate([-offset, offset - 1.0])
    system = np.vstack([constraints.T, limits[None, :]])
    target = np.zeros(system.shape[0])
    target[-1] = 1.0
    weights, _ = optimize.nnls(system, target, maxiter=50 * system.shape[1])
    misfit = system @ weights - target
    if abs(misfit[-1]) < 1e-12:
        raise ValueError("no waveform meets the bounds")
    scaled = -misfit[:-1] / misfit[-1]
    residual = (scaled[:harmonics] + 1j * scaled[harmonics:]) * output_scale
    amplitudes = (residual - line) / gain
    spectrum = np.zeros(int(orders.max()), dtype=complex)
    spectrum[orders - 1] = amplitudes
    values = waveform_values(spectrum, mean, FEASIBILITY_REFINEMENT * phase_points)
    shrink = 1.0
    if values.min() < low:
        shrink = min(shrink, (mean - low) / (mean - values.min()))
    if values.max() > high:
        shrink = min(shrink, (high - mean) / (values.max() - mean))
    return amplitudes * shrink


def residual_lower_bound(line: np.ndarray, gain: np.ndarray, amplitudes: np.ndarray, mean: float, low: float,
                         high: float, floor_gain: float) -> float:
    """A value of ``sum_n |L_n + H_n a_n|**2`` over all harmonics that no waveform goes below.

    Parameters
    ----------
    line, gain : numpy.ndarray
        L_n and H_n for n = 1..N (L_n = 0 above N).
    amplitudes : numpy.ndarray
        A good waveform's a_n (the search for the bound starts from it; any value is valid).
    mean, low, high : float
        The waveform's mean and bounds.
    floor_gain : float
        h with ``h <= |H_n|`` for *every* n, above N too (0 if none is known: then the bound
        covers harmonics 1..N only and holds for waveforms whose higher harmonics are free).

    Returns
    -------
    float
        The bound (output units squared), to the accuracy of a ``BOUND_POINTS``-point quadrature.

    Notes
    -----
    For every waveform, ``sum_n |r_n|**2 >= Phi(P) = sum_{n<=N} (|L_n + H_n a_n|**2 - h**2 |a_n|**2)
    + (h**2 / pi) int (P - mean)**2``, by Parseval (the integral is ``h**2 sum_{all n} |a_n|**2``).
    Phi is convex. Writing its first sum through its conjugate q* and minimising over P pointwise
    gives the dual function ``D(y, lambda) = (1/pi) int min_{low<=P<=high} [P s_y + h**2 (P - mean)**2
    + lambda (P - mean)] - sum q*_n(y_n)``, ``s_y(theta) = Re sum y_n exp(j n theta)``, each of whose
    values is a lower bound; it is maximised from the given waveform's gradient by L-BFGS. With
    h = 0 the pointwise minimum is a rectangular waveform (the mean fixes its width) and D is
    taken at that gradient (a Frank-Wolfe bound).
    """
    line = np.asarray(line, dtype=complex)
    harmonics = line.size
    output_scale = float(np.linalg.norm(line)) or 1.0
    input_scale = high - low
    if input_scale <= 0.0:
        return float(np.sum(np.abs(line) ** 2))
    line = line / output_scale
    gain = np.asarray(gain, dtype=complex) * input_scale / output_scale
    h = floor_gain * input_scale / output_scale
    level = (mean - low) / input_scale                                      # the mean, bounds 0 and 1
    curvature = np.abs(gain) ** 2 - h ** 2
    cross = line * np.conj(gain)

    def negative_dual(z):
        y = z[:harmonics] + 1j * z[harmonics:2 * harmonics]
        lam = z[-1]
        slope = waveform_values(y, 0.0, BOUND_POINTS)
        if h > 0.0:
            power = np.clip(level - (slope + lam) / (2.0 * h * h), 0.0, 1.0)
        else:
            power = _rectangular(slope, level)
        inner = 2.0 * np.mean(power * slope + h * h * (power - level) ** 2 + lam * (power - level))
        conjugate = np.sum(np.abs(y - 2.0 * cross) ** 2 / (4.0 * curvature) - np.abs(line) ** 2)
        slope_y = harmonic_amplitudes(power, harmonics) - (y - 2.0 * cross) / (2.0 * curvature)
        slope_lambda = 2.0 * np.mean(power - level)
        return -(inner - conjugate), -np.concatenate([slope_y.real, slope_y.imag, [slope_lambda]])

    start = 2.0 * curvature * np.asarray(amplitudes) / input_scale + 2.0 * cross   # gradient at the waveform
    z = np.concatenate([start.real, start.imag, [0.0]])
    best = -negative_dual(z)[0]
    if h > 0.0:
        result = optimize.minimize(negative_dual, z, jac=True, method="L-BFGS-B",
                                   options={"maxiter": 500, "ftol": 1e-14, "gtol": 1e-10})
        best = max(best, -float(result.fun))
    return max(best, 0.0) * output_scale ** 2


def _rectangular(slope: np.ndarray, level: float) -> np.ndarray:
    """Values in [0, 1] with mean ``level`` minimising sum(values * slope): 1 where the slope is lowest."""
    count = slope.size
    values = np.zeros(count)
    room = level * count
    order = np.argsort(slope)
    full = min(int(math.floor(room)), count)
    values[order[:full]] = 1.0
    if full < count:
        values[order[full]] = room - full
    return values


__all__ = ["best_bounded_waveform", "harmonic_amplitudes", "largest_fundamental", "residual_lower_bound",
           "waveform_values"]
