"""Thermometry: resistance to temperature and back, from a sensor's calibration file.

Supported files (``docs/explanation/thermometry.md`` has the details and measured accuracy):

* Lake Shore ``.340`` curves, every data format of the Model 340 manual
  (1 = mV/K, 2 = V/K, 3 = Ω/K, 4 = log Ω/K, 5 = log Ω/log K), interpolated
  linearly between breakpoints as Lake Shore controllers do;
* Lake Shore Chebyshev coefficient files (``.cof``), evaluated per fit range
  with Lake Shore's formula;
* raw R-T tables (Lake Shore ``.dat`` test data, two-column text in either
  column order), through a cubic spline of T against log10(R).

A value outside the calibration raises :class:`OutOfCalibrationRange`; a file
that cannot be used raises :class:`CalibrationFileError` naming the file and
the line.

Examples
--------
>>> curve = load_calibration("config/calibration/X186279.340")
>>> round(curve.temperature_K(2776.78), 4)
4.2
>>> round(curve.resistance_ohm(4.2), 2)
2776.78
>>> curve.temperature_K([2776.78, 1000.0]).round(3)
array([ 4.2  , 12.269])
"""

from cryod.thermometry.curve import CalibrationCurve
from cryod.thermometry.errors import CalibrationFileError, OutOfCalibrationRange
from cryod.thermometry.loader import load_calibration

__all__ = ["CalibrationCurve", "CalibrationFileError", "OutOfCalibrationRange", "load_calibration"]
