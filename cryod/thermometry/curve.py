"""What every calibration curve offers, whatever file it came from.

A :class:`CalibrationCurve` converts a sensor reading (a resistance, for the
Cernox thermometers cryod reads) to a temperature and back. Scalars give
floats, arrays give arrays of the same shape. Values outside the calibrated
range raise :class:`~cryod.thermometry.errors.OutOfCalibrationRange`: a curve
never extrapolates.

The subclasses differ only in how they interpolate: straight lines between
breakpoints (:mod:`cryod.thermometry.breakpoints`), Chebyshev series
(:mod:`cryod.thermometry.chebyshev`), a cubic spline through measured points
(:mod:`cryod.thermometry.spline_table`).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from cryod.thermometry.errors import OutOfCalibrationRange

#: What a reading in each sensor unit measures.
QUANTITY_OF_UNIT = {"ohm": "resistance", "V": "voltage", "mV": "voltage", "K": "temperature"}

#: Values this close (relative) outside a calibrated range are taken as its end:
#: rounding, such as 10 ** log10(R) differing from R in the last bit, must not
#: make a value at the edge of the range unusable. Anything further out is refused.
EDGE_ROUNDING = 1e-12


class CalibrationCurve:
    """Sensor reading to temperature and back, for one calibrated sensor.

    Not built directly: :func:`cryod.thermometry.load_calibration` returns the
    subclass that fits the file.

    Parameters
    ----------
    source : str
        The calibration file.
    sensor_model, serial_number : str or None
        From the file header; None when the file does not say (the serial
        number of a raw table or Chebyshev file is its file name, as Lake Shore
        names them).
    sensor_unit : {'ohm', 'V', 'mV'}
        Unit of the readings the curve converts.
    sensor_unit_ranges : sequence of (float, float)
        Covered reading intervals, lowest first.
    temperature_ranges_K : sequence of (float, float)
        Covered temperature intervals, lowest first.
    method : str
        How values between calibration points are found, in one line.

    Attributes
    ----------
    source, sensor_model, serial_number, sensor_unit, method
        As given.
    calibrated_sensor_unit_ranges, calibrated_temperature_ranges_K : list of (float, float)
        As given; more than one interval only for a Chebyshev file whose fit
        ranges leave gaps.
    """

    def __init__(self, *, source: str, sensor_model: str | None, serial_number: str | None,
                 sensor_unit: str, sensor_unit_ranges: Sequence[tuple[float, float]],
                 temperature_ranges_K: Sequence[tuple[float, float]], method: str):
        if sensor_unit not in ("ohm", "V", "mV"):
            raise ValueError(f"sensor unit must be 'ohm', 'V' or 'mV', got {sensor_unit!r}")
        self.source = source
        self.sensor_model = sensor_model
        self.serial_number = serial_number
        self.sensor_unit = sensor_unit
        self.method = method
        self.calibrated_sensor_unit_ranges = sorted((float(low), float(high)) for low, high in sensor_unit_ranges)
        self.calibrated_temperature_ranges_K = sorted((float(low), float(high)) for low, high in temperature_ranges_K)
        self._sensor_unit_windows = _windows(self.calibrated_sensor_unit_ranges)
        self._temperature_windows = _windows(self.calibrated_temperature_ranges_K)
        self._sensor_unit_range = self.sensor_unit_range
        self._temperature_range_K = self.temperature_range_K

    # -- ranges -------------------------------------------------------------
    @property
    def sensor_unit_range(self) -> tuple[float, float]:
        """(lowest, highest) calibrated reading, in ``sensor_unit``."""
        return self.calibrated_sensor_unit_ranges[0][0], self.calibrated_sensor_unit_ranges[-1][1]

    @property
    def resistance_range_ohm(self) -> tuple[float, float]:
        """(lowest, highest) calibrated resistance in ohm."""
        self._require_resistance("resistance_range_ohm")
        return self.sensor_unit_range

    @property
    def temperature_range_K(self) -> tuple[float, float]:
        """(lowest, highest) calibrated temperature in K."""
        return self.calibrated_temperature_ranges_K[0][0], self.calibrated_temperature_ranges_K[-1][1]

    # -- conversions in the sensor's own unit ---------------------------------
    def temperature_K_from_sensor_units(self, reading):
        """Temperature in K for a reading in ``sensor_unit`` (scalar or array)."""
        return self._convert(reading, self._sensor_unit_windows, self.sensor_unit,
                             self._temperature_K, self.temperature_range_K)

    def sensor_units_at(self, temperature_K):
        """Reading in ``sensor_unit`` at ``temperature_K`` (scalar or array)."""
        return self._convert(temperature_K, self._temperature_windows, "K", self._sensor_units,
                             self.sensor_unit_range)

    def sensor_units_per_K(self, temperature_K):
        """d(reading)/dT in ``sensor_unit`` per K at ``temperature_K``."""
        return self._convert(temperature_K, self._temperature_windows, "K",
                             self._sensor_units_per_K)

    # -- conversions for resistance thermometers -----------------------------
    def temperature_K(self, resistance_ohm):
        """Temperature in K for a resistance in ohm.

        Parameters
        ----------
        resistance_ohm : float or array_like

        Returns
        -------
        float or numpy.ndarray
            A float for a scalar, an array of the same shape for an array.

        Raises
        ------
        OutOfCalibrationRange
            Any value outside the calibrated resistance range (or NaN).
        """
        self._require_resistance("temperature_K")
        if isinstance(resistance_ohm, float):        # one reading, as the loop converts each tick
            return self._convert_one(float(resistance_ohm), self._sensor_unit_windows, "ohm", self._temperature_K_of_one,
                                     self._temperature_range_K)
        return self._convert(resistance_ohm, self._sensor_unit_windows, "ohm", self._temperature_K,
                             self._temperature_range_K)

    def resistance_ohm(self, temperature_K):
        """Resistance in ohm at a temperature in K (scalar or array, like :meth:`temperature_K`)."""
        self._require_resistance("resistance_ohm")
        if isinstance(temperature_K, float):         # one temperature, as a simulated DMM reads each tick
            return self._convert_one(float(temperature_K), self._temperature_windows, "K", self._sensor_units_of_one,
                                     self._sensor_unit_range)
        return self._convert(temperature_K, self._temperature_windows, "K", self._sensor_units,
                             self._sensor_unit_range)

    def sensitivity_ohm_per_K(self, temperature_K):
        """dR/dT in ohm/K at a temperature in K (negative for a Cernox)."""
        self._require_resistance("sensitivity_ohm_per_K")
        return self._convert(temperature_K, self._temperature_windows, "K",
                             self._sensor_units_per_K)

    # -- for subclasses -------------------------------------------------------
    def _temperature_K(self, reading):
        """Temperature for readings known to be inside the calibrated range."""
        raise NotImplementedError

    def _sensor_units(self, temperature_K):
        """Readings for temperatures known to be inside the calibrated range."""
        raise NotImplementedError

    def _sensor_units_per_K(self, temperature_K):
        """d(reading)/dT for temperatures known to be inside the calibrated range."""
        raise NotImplementedError

    def _temperature_K_of_one(self, reading: float) -> float:
        """:meth:`_temperature_K` of one float, the same value; a subclass with a cheaper way for one overrides it."""
        return float(self._temperature_K(reading))

    def _sensor_units_of_one(self, temperature_K: float) -> float:
        """:meth:`_sensor_units` of one float, the same value (see :meth:`_temperature_K_of_one`)."""
        return float(self._sensor_units(temperature_K))

    # -- machinery ----------------------------------------------------------
    def _require_resistance(self, what: str) -> None:
        if self.sensor_unit != "ohm":
            raise TypeError(f"{what}: {self.source} calibrates a sensor read in {self.sensor_unit}, "
                            f"not a resistance thermometer; use the *_sensor_units methods")

    def _convert(self, value, windows: list[tuple[float, float, float, float]], unit: str, function: Callable,
                 result_range: tuple[float, float] | None = None):
        """Check ``value`` against the calibrated ``windows``, apply ``function``, keep the result in range.

        A window is (low, high, accepted low, accepted high): values between
        the accepted and the calibrated end are moved onto the end
        (:data:`EDGE_ROUNDING`). Keeping the result inside ``result_range`` only
        absorbs the same kind of rounding on the way out, so that a converted
        value at the edge of the range is always accepted back.
        """
        if isinstance(value, (float, int)) and not isinstance(value, bool):
            for low, high, accepted_low, accepted_high in windows:
                if accepted_low <= value <= accepted_high:
                    result = float(function(min(max(value, low), high)))
                    if result_range is None:
                        return result
                    return min(max(result, result_range[0]), result_range[1])
            raise self._out_of_range(unit, float(value), windows, 1)
        values = np.array(value, dtype=float)
        inside = np.zeros(values.shape, dtype=bool)
        for low, high, accepted_low, accepted_high in windows:
            window = (values >= accepted_low) & (values <= accepted_high)
            values[window] = np.clip(values[window], low, high)
            inside |= window
        if not inside.all():
            outside = values[~inside]
            raise self._out_of_range(unit, float(outside.flat[0]), windows, int(outside.size))
        results = np.asarray(function(values), dtype=float)
        return results if result_range is None else np.clip(results, *result_range)

    def _convert_one(self, value: float, windows: list[tuple[float, float, float, float]], unit: str,
                     function: Callable[[float], float], result_range: tuple[float, float]) -> float:
        """:meth:`_convert` of one float: the same checks, edges and result, without arrays."""
        for low, high, accepted_low, accepted_high in windows:
            if accepted_low <= value <= accepted_high:
                result = function(low if value < low else high if value > high else value)
                low, high = result_range
                return low if result < low else high if result > high else result
        raise self._out_of_range(unit, value, windows, 1)

    def _out_of_range(self, unit: str, value: float, windows, count: int) -> OutOfCalibrationRange:
        ranges = [(low, high) for low, high, _, _ in windows]
        return OutOfCalibrationRange(QUANTITY_OF_UNIT[unit], value, unit, ranges, self.source, count=count)

    def __repr__(self) -> str:
        low, high = self.temperature_range_K
        sensor = self.serial_number or "unknown sensor"
        if self.sensor_model:
            sensor += f" ({self.sensor_model})"
        return f"<{type(self).__name__} {sensor}, {low:.6g} to {high:.6g} K, from {self.source}: {self.method}>"


def _windows(ranges: list[tuple[float, float]]) -> list[tuple[float, float, float, float]]:
    """(low, high, accepted low, accepted high) for each calibrated range."""
    return [(low, high, low - EDGE_ROUNDING * abs(low), high + EDGE_ROUNDING * abs(high)) for low, high in ranges]
