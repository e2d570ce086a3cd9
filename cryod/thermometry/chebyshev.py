"""Chebyshev fits: Lake Shore's own calibration fits, one series per fit range.

Lake Shore ships each calibrated sensor with a ``SerialNumber.COF`` file of
Chebyshev coefficients ("Model 8000 option: disk storage of sensor calibration
data, file description", Lake Shore Cryotronics). Each fit range gives a fit
type (LOG: fit against Z = log10(R); LIN: against Z = R), the bounds Zlower and
Zupper of the fit's variable, the resistance limits between which the range is
used, and the coefficients C(0)..C(m). Per Lake Shore's calibration report,
the temperature is

    k = ((Z - ZL) - (ZU - Z)) / (ZU - ZL),    T = sum_i C(i) cos(i arccos k),

which is the Chebyshev series sum_i C(i) T_i(k) on the interval [ZL, ZU]:
exactly :class:`numpy.polynomial.Chebyshev` with ``domain=[ZL, ZU]``, which
evaluates it (Clenshaw recurrence) and differentiates it for the sensitivity.
A resistance is converted with the range whose resistance limits contain it.

Examples
--------
>>> fit = ChebyshevFitRange("LOG", 2.0, 3.0, 100.0, 1000.0, (10.0, -5.0))
>>> curve = ChebyshevCurve([fit], source="example.cof")
>>> curve.temperature_K(10 ** 2.5)       # k = 0: T = C(0)
10.0
>>> round(curve.resistance_ohm(12.5), 6) # k = -0.5
177.827941
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.polynomial import Chebyshev

from cryod.thermometry.smooth_curve import SmoothCurve
from cryod.thermometry.smooth_response import SmoothResponse

FIT_TYPES = ("LOG", "LIN")

#: How far (in k) resistance limits may reach past [Zlower, Zupper]: the
#: limits are printed with fewer digits than Zlower and Zupper.
K_SLACK = 1e-6


class FitRangeError(ValueError):
    """A fit range that cannot be used; ``number`` is its 1-based place in the file."""

    def __init__(self, number: int, reason: str):
        self.number = number
        self.reason = reason
        super().__init__(f"fit range {number}: {reason}")


@dataclass(frozen=True)
class ChebyshevFitRange:
    """One fit range of a Lake Shore coefficient file.

    Attributes
    ----------
    fit_type : {'LOG', 'LIN'}
        Z = log10(R) or Z = R.
    z_lower, z_upper : float
        Zlower and Zupper of the range.
    lower_limit, upper_limit : float
        Resistance limits (ohm) between which this range is used.
    coefficients : tuple of float
        C(0) .. C(m).
    """

    fit_type: str
    z_lower: float
    z_upper: float
    lower_limit: float
    upper_limit: float
    coefficients: tuple[float, ...]

    def polynomial(self) -> Chebyshev:
        """T(Z) as a numpy Chebyshev series on [Zlower, Zupper]."""
        return Chebyshev(np.asarray(self.coefficients, dtype=float), domain=[self.z_lower, self.z_upper])

    def response(self, unit_name: str = "ohm") -> SmoothResponse:
        """The range as a :class:`SmoothResponse`, after checking that it can be used.

        Raises
        ------
        ValueError
            Unknown fit type, Zupper not above Zlower, limits out of order or
            outside [Zlower, Zupper], or a fit that is not monotonic between its limits.
        """
        if self.fit_type not in FIT_TYPES:
            raise ValueError(f"fit type must be LOG or LIN, got {self.fit_type!r}")
        if not self.z_upper > self.z_lower:
            raise ValueError(f"Zupper ({self.z_upper:g}) must be above Zlower ({self.z_lower:g})")
        if not self.upper_limit > self.lower_limit:
            raise ValueError(f"upper limit ({self.upper_limit:g}) must be above the lower limit "
                             f"({self.lower_limit:g})")
        logarithmic = self.fit_type == "LOG"
        if logarithmic and self.lower_limit <= 0.0:
            raise ValueError(f"a LOG fit needs positive limits, got {self.lower_limit:g}")
        polynomial = self.polynomial()
        z_limits = np.log10([self.lower_limit, self.upper_limit]) if logarithmic else \
            np.array([self.lower_limit, self.upper_limit])
        offset, scale = polynomial.mapparms()
        k_limits = offset + scale * z_limits
        if k_limits[0] < -1.0 - K_SLACK or k_limits[1] > 1.0 + K_SLACK:
            raise ValueError(f"limits {self.lower_limit:g} to {self.upper_limit:g} reach outside "
                             f"Zlower..Zupper ({self.z_lower:g} to {self.z_upper:g})")
        slope = polynomial.deriv()
        turning = [float(root.real) for root in slope.roots()
                   if abs(root.imag) < 1e-9 and z_limits[0] < root.real < z_limits[1]]
        if turning:
            where = 10.0 ** turning[0] if logarithmic else turning[0]
            raise ValueError(f"the fit turns back at {where:.6g} {unit_name}, between its limits")
        return SmoothResponse(polynomial, slope, (self.lower_limit, self.upper_limit),
                              logarithmic=logarithmic, unit_name=unit_name)


class ChebyshevCurve(SmoothCurve):
    """A calibration from Lake Shore Chebyshev fit ranges.

    Parameters
    ----------
    fit_ranges : sequence of ChebyshevFitRange
        In the file's order (the first range whose limits hold a resistance is used).
    source : str
    sensor_model, serial_number : str or None

    Raises
    ------
    FitRangeError
        A range that cannot be used, with its number.
    """

    def __init__(self, fit_ranges: Sequence[ChebyshevFitRange], *, source: str,
                 sensor_model: str | None = None, serial_number: str | None = None):
        responses = []
        for number, fit_range in enumerate(fit_ranges, start=1):
            try:
                responses.append(fit_range.response())
            except ValueError as error:
                raise FitRangeError(number, str(error)) from None
        self.fit_ranges = tuple(fit_ranges)
        types = "/".join(sorted({fit.fit_type for fit in self.fit_ranges}))
        super().__init__(responses, source=source, sensor_model=sensor_model, serial_number=serial_number,
                         sensor_unit="ohm",
                         method=f"Lake Shore Chebyshev fit ({len(self.fit_ranges)} range(s), {types})")
