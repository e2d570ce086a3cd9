"""Raw R-T tables: a cubic spline of T against log10(R) through the measured points.

Lake Shore turns a sensor's test data (``SerialNumber.DAT``, temperature and
resistance pairs) into its interpolation table with "a cubic spline curve
fitting routine" ("Model 8000 option: disk storage of sensor calibration data,
file description", the .TBL and .SPL files). This module does the same with
:class:`scipy.interpolate.CubicSpline` (not-a-knot ends), in the coordinates
Lake Shore uses for negative-temperature-coefficient resistors, T against
log10(R) (data format 4, "log Ω/K": "log resistance vs. kelvin for NTC
resistive sensors", Model 211 manual, 3.13.1). The spline passes through every
measured point; between them, on the tables in ``tests/data/calibration`` it
predicts a left-out point to a median 4e-5 to 6e-5 of its temperature (see
``docs/explanation/thermometry.md``).

A spline can overshoot; one that is not monotonic between the first and the
last point would make a resistance map to two temperatures, so it is refused.

Examples
--------
>>> curve = SplineTableCurve([2.0, 4.0, 8.0, 16.0], [8000.0, 4000.0, 2000.0, 1000.0], source="example.dat")
>>> round(curve.temperature_K(4000.0), 12)
4.0
>>> round(curve.resistance_ohm(curve.temperature_K(3000.0)), 6)
3000.0
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.interpolate import CubicSpline

from cryod.thermometry.smooth_curve import SmoothCurve
from cryod.thermometry.smooth_response import NotMonotonic, SmoothResponse

#: A cubic spline needs this many points (not-a-knot ends).
MINIMUM_POINTS = 4


class SplineTableCurve(SmoothCurve):
    """A calibration from measured (T, R) points, cubic spline in (log10 R, T).

    Parameters
    ----------
    temperatures_K, resistances_ohm : sequence of float
        The measured points, in any order.
    source : str
    sensor_model, serial_number : str or None

    Raises
    ------
    ValueError
        Fewer than 4 points, a repeated resistance or temperature, R not a
        strictly monotonic function of T, or a spline that is not monotonic
        (:class:`~cryod.thermometry.smooth_response.NotMonotonic`).
    """

    def __init__(self, temperatures_K: Sequence[float], resistances_ohm: Sequence[float], *, source: str,
                 sensor_model: str | None = None, serial_number: str | None = None):
        temperatures = np.asarray(temperatures_K, dtype=float)
        resistances = np.asarray(resistances_ohm, dtype=float)
        if temperatures.shape != resistances.shape or temperatures.ndim != 1:
            raise ValueError("temperatures and resistances must be 1-D and of the same length")
        if temperatures.size < MINIMUM_POINTS:
            raise ValueError(f"a spline needs at least {MINIMUM_POINTS} points, got {temperatures.size}")
        if np.any(temperatures <= 0.0) or np.any(resistances <= 0.0):
            raise ValueError("temperatures and resistances must be positive")
        by_temperature = np.argsort(temperatures)
        steps = np.diff(resistances[by_temperature])
        if np.any(np.diff(temperatures[by_temperature]) == 0.0) or not (np.all(steps > 0) or np.all(steps < 0)):
            raise ValueError("resistance must be a strictly monotonic function of temperature")
        order = np.argsort(resistances)
        z = np.log10(resistances[order])
        spline = CubicSpline(z, temperatures[order])
        slope = spline.derivative()
        turning = slope.roots(extrapolate=False)
        turning = turning[(turning > z[0]) & (turning < z[-1])]
        if turning.size:
            raise NotMonotonic(float(10.0 ** turning[0]), "ohm")
        self.temperatures_K = temperatures[order]
        self.resistances_ohm = resistances[order]
        response = SmoothResponse(spline, slope, (resistances[order][0], resistances[order][-1]),
                                  logarithmic=True, interior_z=z[1:-1],
                                  temperature_limits_K=(temperatures[order][0], temperatures[order][-1]))
        super().__init__([response], source=source, sensor_model=sensor_model, serial_number=serial_number,
                         sensor_unit="ohm",
                         method=f"cubic spline of T against log10(R) through {temperatures.size} measured points")
