"""A calibration made of one or more smooth responses side by side.

A Chebyshev coefficient file has several fit ranges, each valid between two
resistance limits; a spline through a raw table is a single one. This module
routes each reading or temperature to the response that covers it.

Adjacent fit ranges share a resistance limit, where their two fits agree only
to the calibration's accuracy (a millikelvin or so), so their temperature spans
can overlap or leave a sliver between them. Touching ranges are therefore
treated as one calibrated interval: a temperature in such a sliver maps to the
shared resistance limit. Ranges that do not touch leave a real gap, which is
out of calibration.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from cryod.thermometry.curve import CalibrationCurve
from cryod.thermometry.smooth_response import SmoothResponse


class SmoothCurve(CalibrationCurve):
    """Calibration from smooth responses, each over its own reading interval.

    Parameters
    ----------
    responses : sequence of SmoothResponse
        In the file's order; where two overlap, the first one listed wins.
    source, sensor_model, serial_number, sensor_unit, method
        As for :class:`~cryod.thermometry.curve.CalibrationCurve`.
    """

    def __init__(self, responses: Sequence[SmoothResponse], *, source: str, sensor_model: str | None,
                 serial_number: str | None, sensor_unit: str, method: str):
        if not responses:
            raise ValueError("a smooth calibration needs at least one response")
        self._responses = list(responses)
        reading_ranges, temperature_ranges = [], []
        for group in _touching_groups(self._responses):
            reading_ranges.append((min(r.reading_low for r in group), max(r.reading_high for r in group)))
            temperature_ranges.append((min(r.temperature_limits_K[0] for r in group),
                                       max(r.temperature_limits_K[1] for r in group)))
        super().__init__(source=source, sensor_model=sensor_model, serial_number=serial_number,
                         sensor_unit=sensor_unit, sensor_unit_ranges=reading_ranges,
                         temperature_ranges_K=temperature_ranges, method=method)

    @property
    def responses(self) -> list[SmoothResponse]:
        return list(self._responses)

    # -- routing ------------------------------------------------------------
    def _route(self, value: float, limits) -> SmoothResponse:
        """The first response whose limits hold ``value``, else the nearest one.

        The nearest one is only ever needed for a temperature in the sliver
        between two touching fit ranges (the calibrated-range check has run).
        """
        for response in self._responses:
            low, high = limits(response)
            if low <= value <= high:
                return response
        return min(self._responses, key=lambda r: min(abs(value - end) for end in limits(r)))

    def _each(self, values, limits, convert):
        if np.ndim(values) == 0:
            return convert(self._route(float(values), limits), values)
        values = np.asarray(values, dtype=float)
        result = np.empty(values.shape)
        pending = np.ones(values.shape, dtype=bool)
        for response in self._responses:
            low, high = limits(response)
            mine = pending & (values >= low) & (values <= high)
            if mine.any():
                result[mine] = convert(response, values[mine])
                pending &= ~mine
        for index in zip(*np.nonzero(pending)):
            result[index] = convert(self._route(float(values[index]), limits), values[index])
        return result

    def _temperature_K(self, reading):
        return self._each(reading, _reading_limits, SmoothResponse.temperature_K)

    def _sensor_units(self, temperature_K):
        return self._each(temperature_K, _temperature_limits, SmoothResponse.reading_at)

    def _sensor_units_per_K(self, temperature_K):
        return self._each(temperature_K, _temperature_limits, SmoothResponse.reading_per_K)


def _reading_limits(response: SmoothResponse) -> tuple[float, float]:
    return response.reading_low, response.reading_high


def _temperature_limits(response: SmoothResponse) -> tuple[float, float]:
    return response.temperature_limits_K


def _touching_groups(responses: Sequence[SmoothResponse]) -> list[list[SmoothResponse]]:
    """Responses grouped into runs whose reading intervals overlap or share an end."""
    groups: list[list[SmoothResponse]] = []
    for response in sorted(responses, key=lambda r: r.reading_low):
        if groups and response.reading_low <= max(r.reading_high for r in groups[-1]):
            groups[-1].append(response)
        else:
            groups.append([response])
    return groups
