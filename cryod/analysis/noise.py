"""The measured noise of a thermometer, from the record itself.

Every significance in ``cryod analyze`` is against this noise, not against the
model's nominal 20 µK / 0.3 mK. It is the white floor of the residual's
spectrum (Welch, Hann windows): the median power spectral density over the
frequencies where neither the model's misfit nor the PTC line lives: above
0.05 Hz, away from every harmonic of the line (and its alias). The median
makes the estimate blind to a few bins of leftover structure.

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 3600.0, 0.08)
>>> noise = np.random.default_rng(1).normal(0.0, 20e-6, t.size)
>>> misfit = 1e-3 * np.sin(10.83 * t) + 1e-3 * np.exp(-t / 200.0)
>>> round(white_noise_rms(noise + misfit, 0.08, 10.83) * 1e6, 0)
20.0
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from cryod.cooler.line import aliased_angular_frequency

#: Below this frequency (Hz) the residual holds slow misfit, not noise.
LOWEST_NOISE_FREQUENCY_HZ = 0.05
#: Half-width (Hz) of the band left out around each harmonic of the line.
LINE_EXCLUSION_HZ = 0.06
#: Harmonics of the line left out (aliases included).
EXCLUDED_ORDERS = 8


def without_linear_trend(segment: np.ndarray) -> np.ndarray:
    """A segment less its least-squares straight line (along the last axis).

    What ``scipy.signal.detrend(segment, type="linear")`` gives, as one projection onto an orthogonal pair
    (a constant and a centred ramp) instead of a least-squares solve per segment: ``welch`` calls it once per
    segment, some hundred times per residual.

    Examples
    --------
    >>> np.round(without_linear_trend(np.array([1.0, 3.0, 5.0, 8.0])), 3)
    array([ 0.2, -0.1, -0.4,  0.3])
    """
    segment = np.asarray(segment, dtype=float)
    ramp = np.arange(segment.shape[-1]) - 0.5 * (segment.shape[-1] - 1)
    slope = (segment @ ramp) / (ramp @ ramp)
    return segment - segment.mean(axis=-1, keepdims=True) - np.multiply.outer(slope, ramp)


def white_noise_rms(residual, sample_interval_s: float, line_angular_frequency_rad_s: float | None = None) -> float:
    """Rms of the white part of a residual.

    Parameters
    ----------
    residual : array_like
        Measured minus modelled, in sample order (jitter in the instants is
        ignored; it does not colour white noise).
    sample_interval_s : float
        Typical interval between samples (s).
    line_angular_frequency_rad_s : float, optional
        The PTC line; its harmonics are left out of the floor.

    Returns
    -------
    float
        Noise rms in the units of ``residual``.
    """
    residual = np.asarray(residual, dtype=float)
    residual = residual[np.isfinite(residual)]
    if residual.size < 64:
        return float(np.std(np.diff(residual)) / math.sqrt(2.0)) if residual.size > 2 else math.nan
    sampling_hz = 1.0 / sample_interval_s
    segment = int(min(1024, max(64, residual.size // 8)))
    frequency, density = signal.welch(residual - residual.mean(), fs=sampling_hz, nperseg=segment,
                                      window="hann", detrend=without_linear_trend)
    keep = frequency >= max(LOWEST_NOISE_FREQUENCY_HZ, 3.0 * sampling_hz / segment)
    keep &= frequency < 0.5 * sampling_hz * 0.98
    if line_angular_frequency_rad_s:
        for order in range(1, EXCLUDED_ORDERS + 1):
            alias = aliased_angular_frequency(order * line_angular_frequency_rad_s, sample_interval_s) / (2.0 * math.pi)
            keep &= np.abs(frequency - alias) > max(LINE_EXCLUSION_HZ, 2.0 * sampling_hz / segment)
    if np.count_nonzero(keep) < 5:
        keep = frequency > 0
    # one-sided density of white noise of variance s^2 is 2 s^2 / fs
    floor = float(np.median(density[keep]))
    return math.sqrt(floor * sampling_hz / 2.0)
