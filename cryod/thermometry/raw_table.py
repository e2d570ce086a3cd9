"""Reading raw R-T tables: Lake Shore test data (``.dat``) and plain two-column text.

A Lake Shore test data file (``SerialNumber.DAT``; "Model 8000 option: disk
storage of sensor calibration data, file description") has a few header lines,
then one measured point per line, temperature first::

    Temperature             Resistance
    (Kelvin)                (Ohms)

    1.20048138703863E+00   3.20545632182936E+04

A plain table has the same two numbers per line, in either order, separated by
spaces, tabs, commas or semicolons, with or without a header, in any sort
order. Lines starting with ``#`` are comments anywhere.

Which column is the temperature:

1. a header line naming the columns decides it (``Temperature``, ``T``,
   ``Kelvin``, ``K`` against ``Resistance``, ``R``, ``Ohms``, ``ohm``, with or
   without units such as ``T_K`` or ``R[ohm]``);
2. without one, the column whose values could all be temperatures of a
   calibrated sensor (0 to 500 K) is the temperature, if the other could not be
   (it holds a value above 500, which for a Cernox any table reaching the
   helium range does);
3. otherwise the file is refused, with a message asking for a header line:
   guessing wrong would silently turn resistances into temperatures.

The serial number is taken from the file name (Lake Shore names these files
by serial number); the sensor model is not known.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from cryod.thermometry.smooth_response import NotMonotonic
from cryod.thermometry.source_text import CalibrationText, NumberedLine
from cryod.thermometry.spline_table import MINIMUM_POINTS, SplineTableCurve

#: Above this no value in a column can be a calibrated sensor's temperature (K).
HIGHEST_PLAUSIBLE_TEMPERATURE_K = 500.0

_SEPARATORS = re.compile(r"[\s,;]+")
_FIRST_WORD = re.compile(r"[^\W\d_]+")
TEMPERATURE_WORDS = {"t", "temp", "temperature", "kelvin", "k"}
RESISTANCE_WORDS = {"r", "res", "resistance", "ohm", "ohms", "ω"}


def read_raw_table(text: CalibrationText) -> SplineTableCurve:
    """Parse a raw R-T table into a :class:`SplineTableCurve`.

    Raises
    ------
    CalibrationFileError
        A line that is not two numbers, fewer than 4 points, columns that
        cannot be told apart, a repeated temperature, resistance that is not
        a strictly monotonic function of temperature, or a spline through the
        points that is not monotonic.
    """
    header: list[NumberedLine] = []
    rows: list[tuple[float, float]] = []
    row_lines: list[int] = []
    for line in text.content_lines():
        stripped = line.text.strip()
        if stripped.startswith("#"):
            continue
        fields = [field for field in _SEPARATORS.split(stripped) if field]
        if not rows and not _is_number(fields[0]):
            header.append(line)
            continue
        if len(fields) != 2:
            raise text.error(line.number, f"expected 2 numbers (temperature and resistance), got "
                                          f"{len(fields)} fields")
        rows.append((text.number(fields[0], line.number, "column 1"),
                     text.number(fields[1], line.number, "column 2")))
        row_lines.append(line.number)
    if len(rows) < MINIMUM_POINTS:
        raise text.error(text.last_line_number if text.lines else None,
                         f"a table needs at least {MINIMUM_POINTS} points, found {len(rows)}")
    temperature_column = _temperature_column(text, header, rows, row_lines)
    temperatures = [row[temperature_column] for row in rows]
    resistances = [row[1 - temperature_column] for row in rows]
    for index, (temperature, resistance) in enumerate(zip(temperatures, resistances)):
        if temperature <= 0.0 or resistance <= 0.0:
            raise text.error(row_lines[index], f"temperature and resistance must be positive, got "
                                               f"T = {temperature:g} K, R = {resistance:g} ohm")
    _require_monotonic(text, temperatures, resistances, row_lines)
    try:
        return SplineTableCurve(temperatures, resistances, source=text.source, serial_number=Path(text.source).stem)
    except NotMonotonic as error:
        turning_ohm = error.reading
        nearest = min(range(len(resistances)), key=lambda index: abs(math.log(resistances[index] / turning_ohm)))
        raise text.error(row_lines[nearest], f"the cubic spline through the table turns back near "
                                             f"{turning_ohm:.6g} ohm, so one resistance would give two "
                                             f"temperatures; the points around this line are too uneven "
                                             f"for a spline") from None


def _is_number(field: str) -> bool:
    try:
        float(field)
    except ValueError:
        return False
    return True


def _temperature_column(text: CalibrationText, header: list[NumberedLine], rows, row_lines) -> int:
    for line in header:
        words = [word for word in _SEPARATORS.split(line.text.strip()) if word]
        kinds = [_column_kind(word) for word in words]
        if len(words) == 2 and sorted(map(str, kinds)) == ["R", "T"]:
            return kinds.index("T")
    could_be_temperature = [all(0.0 < row[column] <= HIGHEST_PLAUSIBLE_TEMPERATURE_K for row in rows)
                            for column in (0, 1)]
    if could_be_temperature.count(True) == 1:
        return could_be_temperature.index(True)
    where = header[0].number if header else row_lines[0]
    raise text.error(where, "cannot tell which column is the temperature: "
                            + ("both" if all(could_be_temperature) else "neither")
                            + f" could hold temperatures (0 to {HIGHEST_PLAUSIBLE_TEMPERATURE_K:g} K); "
                              "add a header line such as 'Temperature Resistance' or 'R_ohm T_K'")


def _column_kind(word: str) -> str | None:
    """'T' or 'R' for a column title such as 'Temperature', '(Kelvin)', 'T_K', 'R[ohm]'."""
    first = _FIRST_WORD.search(word)
    name = first.group(0).lower() if first else ""
    return "T" if name in TEMPERATURE_WORDS else "R" if name in RESISTANCE_WORDS else None


def _require_monotonic(text: CalibrationText, temperatures, resistances, row_lines) -> None:
    order = sorted(range(len(temperatures)), key=lambda index: temperatures[index])
    falls = resistances[order[-1]] < resistances[order[0]]
    for previous, index in zip(order, order[1:]):
        if temperatures[index] == temperatures[previous]:
            raise text.error(row_lines[index], f"temperature {temperatures[index]:g} K appears twice "
                                               f"(also line {row_lines[previous]})")
        step = resistances[index] - resistances[previous]
        if step == 0.0 or (step < 0.0) != falls:
            trend = "falls" if falls else "rises"
            raise text.error(row_lines[index], f"resistance {resistances[index]:g} ohm at {temperatures[index]:g} K "
                                               f"breaks the trend of the table (resistance {trend} with "
                                               f"temperature; line {row_lines[previous]} has "
                                               f"{resistances[previous]:g} ohm at {temperatures[previous]:g} K)")
