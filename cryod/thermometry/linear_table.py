"""One value at a time through a table of breakpoints: straight lines between them.

:func:`numpy.interp` is made for arrays. For the one reading a thermometer gives each tick it
converts its arguments to arrays, lets go of the interpreter lock (another thread may then hold
the loop up) and returns a numpy scalar: a few microseconds for a few nanoseconds of arithmetic.
:class:`LinearTable` keeps the breakpoints as Python floats with each segment's slope computed
once, finds the segment by bisection and does numpy's own arithmetic (the segment's slope times
the distance from its lower breakpoint, plus that breakpoint's value), so that its results are
:func:`numpy.interp`'s to the last bit.

Examples
--------
>>> table = LinearTable([1.0, 2.0, 4.0], [10.0, 20.0, 30.0])
>>> table(1.5), table(3.0), table(4.0)
(15.0, 25.0, 30.0)
"""

from __future__ import annotations

from bisect import bisect_right
from typing import Iterable


class LinearTable:
    """Linear interpolation of one float between breakpoints, as :func:`numpy.interp` does it.

    Parameters
    ----------
    x : iterable of float
        The abscissae, strictly increasing (a list or an array).
    y : iterable of float
        The values at ``x``.

    Notes
    -----
    Outside ``[x[0], x[-1]]`` it returns the end value, as :func:`numpy.interp` does; the
    calibration curves never ask it there (they refuse such a reading first).
    """

    __slots__ = ("_x", "_y", "_slopes", "_last")

    def __init__(self, x: Iterable[float], y: Iterable[float]):
        self._x = [float(value) for value in x]
        self._y = [float(value) for value in y]
        if len(self._x) != len(self._y) or len(self._x) < 2:
            raise ValueError("a linear table needs at least 2 (x, y) pairs of equal length")
        if any(b <= a for a, b in zip(self._x, self._x[1:])):
            raise ValueError("the abscissae of a linear table must be strictly increasing")
        self._slopes = [(self._y[j + 1] - self._y[j]) / (self._x[j + 1] - self._x[j]) for j in range(len(self._x) - 1)]
        self._last = len(self._x) - 1

    def __call__(self, value: float) -> float:
        """The value at ``value`` (a float), numpy.interp's to the last bit."""
        x = self._x
        j = bisect_right(x, value) - 1
        if j < 0 or value != value:                                # below the table, or NaN (stays NaN)
            return self._y[0] if value == value else value
        if j >= self._last or x[j] == value:
            return self._y[j]
        slope = self._slopes[j]
        result = slope * (value - x[j]) + self._y[j]
        if result != result:                 # as numpy: from the upper breakpoint when the lower gives NaN
            result = slope * (value - x[j + 1]) + self._y[j + 1]
            if result != result and self._y[j] == self._y[j + 1]:
                result = self._y[j]
        return result
