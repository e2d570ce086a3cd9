"""The two ways a calibration can refuse: a file it cannot use, a value it does not cover."""

from __future__ import annotations

from typing import Sequence

from cryod.yaml_source import FileFormatError


class CalibrationFileError(FileFormatError):
    """A calibration file that cannot be used, with the file, the line and why.

    A subclass of :class:`cryod.yaml_source.FileFormatError`, so code that loads
    a configuration and the calibration files it names can catch both with one
    clause. The message reads ``X186279.340:12: breakpoint 4: expected 3 fields
    (number, units, temperature), got 2``.

    Attributes
    ----------
    source : str
        The file's path.
    line : int or None
        1-based line number, None for whole-file problems (unreadable, empty).
    reason : str
        What is wrong, in words a user can act on.
    """

    def __init__(self, source: str, line: int | None, reason: str):
        super().__init__(source, line, "", reason)


class OutOfCalibrationRange(ValueError):
    """A resistance (or temperature) the calibration does not cover.

    Raised instead of extrapolating: a reading outside the calibrated range
    is a fault to act on (a broken lead, a sensor far from its setpoint), never
    a temperature.

    Attributes
    ----------
    quantity : str
        ``"resistance"``, ``"temperature"``, ``"voltage"``, ...
    value : float
        The offending value (the first one, for an array), in ``unit``.
    unit : str
        ``"ohm"``, ``"K"``, ``"V"`` or ``"mV"``.
    calibrated_ranges : list of (float, float)
        The covered intervals, in ``unit``, lowest first; more than one when
        a Chebyshev fit file leaves gaps between its fit ranges.
    source : str
        The calibration file.
    count : int
        How many values of the input were out of range.

    Examples
    --------
    >>> error = OutOfCalibrationRange("resistance", 12.0, "ohm", [(63.1, 32054.6)], "X1.dat")
    >>> str(error)
    'resistance 12 ohm is outside the calibrated range 63.1 to 32054.6 ohm of X1.dat'
    >>> isinstance(error, ValueError)
    True
    """

    def __init__(self, quantity: str, value: float, unit: str,
                 calibrated_ranges: Sequence[tuple[float, float]], source: str, count: int = 1):
        self.quantity = quantity
        self.value = value
        self.unit = unit
        self.calibrated_ranges = [(float(low), float(high)) for low, high in calibrated_ranges]
        self.source = source
        self.count = count
        covered = " and ".join(f"{low:.6g} to {high:.6g}" for low, high in self.calibrated_ranges)
        plural = "ranges" if len(self.calibrated_ranges) > 1 else "range"
        message = f"{quantity} {value:.6g} {unit} is outside the calibrated {plural} {covered} {unit} of {source}"
        if count > 1:
            message += f" ({count} values out of range)"
        super().__init__(message)
