"""A smooth, monotonic T(z) on one reading interval, with its inverse and its slope.

Chebyshev fit ranges and splines through raw tables both give temperature as
a smooth function of z = log10(R) (or of R itself). Going back, from a
temperature to a resistance, has no closed form. :class:`SmoothResponse`
tabulates z(T) once, densely, with the exact slopes, as a cubic Hermite
interpolant (:class:`scipy.interpolate.CubicHermiteSpline`), and refines the
table until a round trip T -> z -> T is exact to ``relative_tolerance``
everywhere it was checked (mid- and quarter-points of every table interval,
where a Hermite interpolant's error is largest). A scalar inverse then costs
one spline evaluation, a few microseconds, which matters because the
simulated multimeter converts a temperature to a resistance on every reading.

Examples
--------
>>> import numpy as np
>>> response = SmoothResponse(lambda z: 100.0 / z, lambda z: -100.0 / z**2, (10.0, 1000.0), logarithmic=True)
>>> response.temperature_limits_K
(33.333333333333336, 100.0)
>>> round(float(response.temperature_K(100.0)), 12)        # z = 2
50.0
>>> round(response.reading_at(50.0), 9)
100.0
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
from scipy.interpolate import CubicHermiteSpline

LN10 = math.log(10.0)


class NotMonotonic(ValueError):
    """The response turns back (or stalls) somewhere in its interval; ``reading`` says where."""

    def __init__(self, reading: float, unit_name: str):
        self.reading = reading
        super().__init__(f"temperature is not a strictly monotonic function of the reading "
                         f"near {reading:.6g} {unit_name}")


class SmoothResponse:
    """Temperature as a smooth, strictly monotonic function of a reading, and back.

    Parameters
    ----------
    temperature_of_z : callable
        T in K as a function of z (array in, array out).
    slope_of_z : callable
        dT/dz (array in, array out).
    reading_limits : (float, float)
        The reading interval covered (ohm, or the sensor's unit), low first.
    logarithmic : bool
        z = log10(reading) when True, z = reading when False.
    interior_z : sequence of float, optional
        Points where the response's higher derivatives jump (spline knots);
        the inverse table never straddles one.
    relative_tolerance : float
        Largest |T(z(T)) - T| / T accepted for the tabulated inverse.
    temperature_limits_K : (float, float), optional
        The temperatures at the reading limits when the calibration states
        them (the end points of a measured table), so that they are inside
        the calibrated range to the last digit; by default T at the limits.

    Raises
    ------
    NotMonotonic
        If the slope changes sign or vanishes on the interval (sampled on the
        inverse table; callers that can find the slope's roots exactly do so first).
    """

    def __init__(self, temperature_of_z: Callable, slope_of_z: Callable, reading_limits: tuple[float, float],
                 *, logarithmic: bool, interior_z: Sequence[float] = (), relative_tolerance: float = 1e-11,
                 temperature_limits_K: tuple[float, float] | None = None, unit_name: str = "ohm"):
        self.reading_low, self.reading_high = float(reading_limits[0]), float(reading_limits[1])
        if not self.reading_low < self.reading_high:
            raise ValueError(f"reading limits must rise, got {reading_limits}")
        if logarithmic and self.reading_low <= 0.0:
            raise ValueError("a logarithmic response needs positive readings")
        self.logarithmic = logarithmic
        self.unit_name = unit_name
        self._temperature_of_z = temperature_of_z
        self._slope_of_z = slope_of_z
        self.z_low, self.z_high = self.z_of(self.reading_low), self.z_of(self.reading_high)
        inner = np.asarray(interior_z, dtype=float)
        nodes = np.concatenate(([self.z_low], inner[(inner > self.z_low) & (inner < self.z_high)], [self.z_high]))
        self._inverse = self._tabulate_inverse(np.unique(nodes), relative_tolerance)
        ends = sorted((float(temperature_of_z(self.z_low)), float(temperature_of_z(self.z_high))))
        if temperature_limits_K is not None:
            stated = sorted(float(limit) for limit in temperature_limits_K)
            if not np.allclose(stated, ends, rtol=1e-9, atol=0.0):
                raise ValueError(f"stated temperature limits {stated} differ from the response's {ends}")
            ends = stated
        self.temperature_limits_K = (ends[0], ends[1])

    def z_of(self, reading):
        return np.log10(reading) if self.logarithmic else reading

    def _tabulate_inverse(self, nodes: np.ndarray, relative_tolerance: float) -> CubicHermiteSpline:
        subdivisions = 4
        while True:
            fractions = np.arange(subdivisions) / subdivisions
            z = np.append((nodes[:-1, None] + np.diff(nodes)[:, None] * fractions).ravel(), nodes[-1])
            temperatures = self._temperature_of_z(z)
            slopes = self._slope_of_z(z)
            self._require_monotonic(z, temperatures, slopes)
            order = np.argsort(temperatures)
            inverse = CubicHermiteSpline(temperatures[order], z[order], 1.0 / slopes[order])
            probes = (temperatures[order][:-1, None] + np.diff(temperatures[order])[:, None]
                      * np.array([0.25, 0.5, 0.75])).ravel()
            error = np.abs(self._temperature_of_z(inverse(probes)) - probes) / probes
            if error.max() <= relative_tolerance:
                return inverse
            if subdivisions >= 4096:
                raise ValueError(f"cannot tabulate the inverse to {relative_tolerance:g} "
                                 f"(worst {error.max():.3g} near {probes[np.argmax(error)]:.6g} K)")
            subdivisions *= 4

    def _require_monotonic(self, z, temperatures, slopes) -> None:
        sign = np.sign(slopes[0])
        steps = np.diff(temperatures) * sign
        bad = np.flatnonzero((np.sign(slopes) != sign) | (slopes == 0.0))
        if bad.size == 0 and np.any(steps <= 0.0):
            bad = np.flatnonzero(steps <= 0.0) + 1
        if bad.size:
            reading = 10.0 ** z[bad[0]] if self.logarithmic else z[bad[0]]
            raise NotMonotonic(float(reading), self.unit_name)

    # -- conversions (inputs already checked against the limits) -----------
    def temperature_K(self, reading):
        """T in K at readings inside the limits."""
        return self._temperature_of_z(self.z_of(reading))

    def reading_at(self, temperature_K):
        """Reading at temperatures inside ``temperature_limits_K`` (kept inside the reading limits)."""
        z = self._inverse(temperature_K)
        reading = 10.0 ** z if self.logarithmic else z
        if reading.ndim == 0:
            return min(max(float(reading), self.reading_low), self.reading_high)
        return np.clip(reading, self.reading_low, self.reading_high)

    def reading_per_K(self, temperature_K):
        """d(reading)/dT at temperatures inside ``temperature_limits_K``."""
        reading = self.reading_at(temperature_K)
        dz_dT = 1.0 / self._slope_of_z(self.z_of(reading))
        return LN10 * reading * dz_dT if self.logarithmic else dz_dT
