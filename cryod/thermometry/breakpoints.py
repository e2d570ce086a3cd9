"""Breakpoint curves: straight lines between breakpoints, as Lake Shore controllers interpolate.

A Lake Shore curve (``.340`` file, or the CRVHDR/CRVPT curve of a controller)
is a table of up to 200 breakpoints, each a value in *sensor units* and a
temperature in kelvin. The curve header's data format says what the sensor
units are. The data formats are those of the Model 340 manual (CRVHDR command,
p. 9-29: "1 = mV/K, 2 = V/K, 3 = Ω/K, 4 = log Ω/K, 5 = log Ω/log K"); later
controllers (331, 335, 336) accept formats 1 to 4 of the same list.

Between breakpoints the controller interpolates linearly, in the coordinates
of the data format (Model 346 User's Manual, 5.5 "Curve Related Commands":
"the breakpoint table is used to convert the raw sensor reading into a
temperature reading using linear interpolation between the two nearest
points"). So a log Ω/K curve is a straight line in (log10 R, T) between
breakpoints, and a log Ω/log K curve a straight line in (log10 R, log10 T).
Where the controller then extrapolates up to 50 % beyond the table, this
module refuses: outside the breakpoints there is no calibration.

For the log Ω/log K format the temperature column stays in kelvin, as in
every format: the CRVPT command that loads a breakpoint takes "the
corresponding temperature in kelvin" whatever the format (Model 331 manual,
CRVPT; Model 372 manual, 6.6.1); only the interpolation is in log10 T.

Examples
--------
>>> curve = BreakpointCurve([2.0, 3.0], [40.0, 4.0], DATA_FORMATS[4], source="example.340")
>>> curve.temperature_K(10 ** 2.5)            # half way in log10(R): half way in T
22.0
>>> round(curve.resistance_ohm(22.0), 6)
316.227766
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.interpolate import make_interp_spline

from cryod.thermometry.curve import CalibrationCurve
from cryod.thermometry.linear_table import LinearTable

LN10 = math.log(10.0)


@dataclass(frozen=True)
class DataFormat:
    """One Lake Shore curve data format.

    Attributes
    ----------
    code : int
        The number in the curve header (``Data Format:`` of a .340 file).
    name : str
        As the manuals write it.
    sensor_unit : str
        Unit of the sensor reading: 'mV', 'V' or 'ohm'.
    units_are_log10 : bool
        The sensor-units column holds log10 of the reading (log Ω formats).
    temperature_is_log10 : bool
        Interpolation is linear in log10 T rather than T.
    """

    code: int
    name: str
    sensor_unit: str
    units_are_log10: bool
    temperature_is_log10: bool


#: The data formats of the Model 340 manual (CRVHDR), by code.
DATA_FORMATS = {
    1: DataFormat(1, "mV/K", "mV", False, False),
    2: DataFormat(2, "V/K", "V", False, False),
    3: DataFormat(3, "ohm/K", "ohm", False, False),
    4: DataFormat(4, "log ohm/K", "ohm", True, False),
    5: DataFormat(5, "log ohm/log K", "ohm", True, True),
}


class BreakpointCurve(CalibrationCurve):
    """A Lake Shore breakpoint curve, interpolated linearly in its data format's coordinates.

    Parameters
    ----------
    sensor_units : sequence of float
        The breakpoints' sensor-units column, as in the file (log10 of the
        resistance for the log Ω formats).
    temperatures_K : sequence of float
        The breakpoints' temperatures in K.
    data_format : DataFormat
    source : str
        The file the breakpoints came from.
    sensor_model, serial_number : str or None
    setpoint_limit_K : float or None
        The header's setpoint limit (not used for conversion).

    Raises
    ------
    ValueError
        Fewer than 2 breakpoints, or sensor units or temperatures that are not
        strictly monotonic (the .340 reader reports these with the line first).
    """

    def __init__(self, sensor_units: Sequence[float], temperatures_K: Sequence[float], data_format: DataFormat,
                 *, source: str, sensor_model: str | None = None, serial_number: str | None = None,
                 setpoint_limit_K: float | None = None):
        units = np.asarray(sensor_units, dtype=float)
        temperatures = np.asarray(temperatures_K, dtype=float)
        if units.shape != temperatures.shape or units.ndim != 1 or units.size < 2:
            raise ValueError("a breakpoint curve needs at least 2 (units, temperature) pairs")
        if np.any(temperatures <= 0.0):
            raise ValueError("breakpoint temperatures must be above 0 K")
        order = np.argsort(units)
        x = units[order]                       # interpolation abscissa: sensor units, increasing
        y = np.log10(temperatures[order]) if data_format.temperature_is_log10 else temperatures[order]
        if np.any(np.diff(x) <= 0.0) or not (np.all(np.diff(y) > 0.0) or np.all(np.diff(y) < 0.0)):
            raise ValueError("breakpoint sensor units and temperatures must both be strictly monotonic")
        self.data_format = data_format
        self.setpoint_limit_K = setpoint_limit_K
        self.breakpoint_sensor_units = units.copy()
        self.breakpoint_temperatures_K = temperatures.copy()
        self._x = x
        self._y = y
        rising = y[-1] > y[0]
        self._y_increasing = y if rising else y[::-1].copy()
        self._x_by_y = x if rising else x[::-1].copy()
        self._dx_dy = make_interp_spline(self._y_increasing, self._x_by_y, k=1).derivative()
        # one reading at a time (the loop's, a simulated DMM's): the same lines, without numpy's arrays
        self._y_of_x = LinearTable(x, y)
        self._x_of_y = LinearTable(self._y_increasing, self._x_by_y)
        reading_limits = (10.0 ** x[0], 10.0 ** x[-1]) if data_format.units_are_log10 else (x[0], x[-1])
        super().__init__(source=source, sensor_model=sensor_model, serial_number=serial_number,
                         sensor_unit=data_format.sensor_unit, sensor_unit_ranges=[reading_limits],
                         temperature_ranges_K=[(temperatures.min(), temperatures.max())],
                         method=f"linear between breakpoints in ({self._x_name()}, "
                                f"{'log10 T' if data_format.temperature_is_log10 else 'T'}), "
                                f"Lake Shore data format {data_format.code} ({data_format.name})")

    def _x_name(self) -> str:
        unit = self.data_format.sensor_unit
        return f"log10 {unit}" if self.data_format.units_are_log10 else unit

    # reading -> temperature
    def _temperature_K(self, reading):
        x = np.log10(reading) if self.data_format.units_are_log10 else reading
        y = np.interp(x, self._x, self._y)
        return 10.0 ** y if self.data_format.temperature_is_log10 else y

    def _temperature_K_of_one(self, reading: float) -> float:
        x = float(np.log10(reading)) if self.data_format.units_are_log10 else reading
        y = self._y_of_x(x)
        return 10.0 ** y if self.data_format.temperature_is_log10 else y

    # temperature -> reading
    def _sensor_units(self, temperature_K):
        y = np.log10(temperature_K) if self.data_format.temperature_is_log10 else temperature_K
        x = np.interp(y, self._y_increasing, self._x_by_y)
        return 10.0 ** x if self.data_format.units_are_log10 else x

    def _sensor_units_of_one(self, temperature_K: float) -> float:
        y = float(np.log10(temperature_K)) if self.data_format.temperature_is_log10 else temperature_K
        x = self._x_of_y(y)
        return 10.0 ** x if self.data_format.units_are_log10 else x

    def _sensor_units_per_K(self, temperature_K):
        """Chain rule through the segment slope (at a breakpoint: the segment on its warmer side)."""
        temperature_K = np.asarray(temperature_K, dtype=float)
        if self.data_format.temperature_is_log10:
            y = np.log10(temperature_K)
            dy_dT = 1.0 / (temperature_K * LN10)
        else:
            y, dy_dT = temperature_K, 1.0
        dx_dT = self._dx_dy(y) * dy_dT
        if self.data_format.units_are_log10:
            return LN10 * self._sensor_units(temperature_K) * dx_dT
        return dx_dT
