"""Reading Lake Shore Chebyshev coefficient files (``.cof``).

Layout (Lake Shore, "Model 8000 option: disk storage of sensor calibration
data, file description", the coefficient file)::

    Number of fit ranges: 2
    FIT RANGE: 1
    Fit type for range 1: LOG
    Order of fit range 1: 9
    Zlower for fit range 1: 2.91027046513
    Zupper for fit range 1: 4.50588986348
    Lower Resist. limit for fit range 1: 898.60
    Upper Resist. limit for fit range 1: 21226.3
    C(0) Equation 1: 5.347944
    ...
    C(9) Equation 1: 0.002030
    FIT RANGE: 2
    ...

Label wording and spacing vary between files (Lake Shore's own example writes
"Fit range: 1", "Lower limit for fit range 1" and numbers every coefficient
line "Equation 1" even in range 2), so lines are recognised by the start of
their label, without regard to case or spaces, and the range and equation
numbers inside the labels are not relied on; the ``FIT RANGE`` lines must
count 1, 2, ... and the coefficients C(0), C(1), ... in order, m + 1 of them
for a fit of order m. Errors name the file and the line.

The file names no sensor model; the serial number is taken from the file name
(Lake Shore names the file ``SerialNumber.COF``).
"""

from __future__ import annotations

import re
from pathlib import Path

from cryod.thermometry.chebyshev import FIT_TYPES, ChebyshevCurve, ChebyshevFitRange, FitRangeError
from cryod.thermometry.source_text import CalibrationText, NumberedLine, label_and_value, leading_field

_COEFFICIENT_INDEX = re.compile(r"^c\((\d+)\)")

#: Field of a fit range, by the start of its label (lower case, spaces removed).
RANGE_FIELDS = (
    ("fittype", "fit_type"),
    ("order", "order"),
    ("zlower", "z_lower"),
    ("zupper", "z_upper"),
    ("lower", "lower_limit"),
    ("upper", "upper_limit"),
)
FIELD_WORDS = {"fit_type": "fit type", "order": "order of fit", "z_lower": "Zlower", "z_upper": "Zupper",
               "lower_limit": "lower limit", "upper_limit": "upper limit"}


def read_cof(text: CalibrationText) -> ChebyshevCurve:
    """Parse a Chebyshev coefficient file into a :class:`ChebyshevCurve`.

    Raises
    ------
    CalibrationFileError
        Missing or unrecognised lines, ranges out of sequence or fewer than
        announced, a wrong number of coefficients, or a range that cannot be
        used (limits outside Zlower..Zupper, a fit that is not monotonic).
    """
    lines = text.content_lines()
    if not lines:
        raise text.error(None, "file is empty")
    label, value = _compact_label(lines[0])
    if not label.startswith("numberoffitranges"):
        raise text.error(lines[0].number, f"expected 'Number of fit ranges: N' as the first line, "
                                          f"got {lines[0].text.strip()!r}")
    announced = text.whole_number(leading_field(value), lines[0].number, "number of fit ranges")
    if announced < 1:
        raise text.error(lines[0].number, f"number of fit ranges must be at least 1, got {announced}")
    blocks = _range_blocks(text, lines[1:], announced, lines[0].number)
    fit_ranges = [_read_range(text, number, start, body) for number, (start, body) in enumerate(blocks, start=1)]
    try:
        return ChebyshevCurve(fit_ranges, source=text.source, serial_number=Path(text.source).stem)
    except FitRangeError as error:
        raise text.error(blocks[error.number - 1][0].number, str(error)) from None


def _compact_label(line: NumberedLine) -> tuple[str, str]:
    label, value = label_and_value(line.text)
    return label.replace(" ", ""), value


def _range_blocks(text: CalibrationText, lines: list[NumberedLine], announced: int, announce_line: int):
    """The lines of each fit range: (its 'FIT RANGE: n' line, the lines after it)."""
    blocks: list[tuple[NumberedLine, list[NumberedLine]]] = []
    for line in lines:
        label, value = _compact_label(line)
        if label.startswith("fitrange"):
            expected = len(blocks) + 1
            if expected > announced:
                raise text.error(line.number, f"more fit ranges than the {announced} announced on line "
                                              f"{announce_line}")
            number = text.whole_number(leading_field(value), line.number, "fit range number")
            if number != expected:
                raise text.error(line.number, f"fit range {number} out of sequence (expected {expected})")
            blocks.append((line, []))
        elif not blocks:
            raise text.error(line.number, f"expected 'FIT RANGE: 1', got {line.text.strip()!r}")
        else:
            blocks[-1][1].append(line)
    if len(blocks) < announced:
        raise text.error(text.last_line_number, f"the file ends after {len(blocks)} of the {announced} fit ranges "
                                                f"announced on line {announce_line}: truncated?")
    return blocks


def _read_range(text: CalibrationText, number: int, start: NumberedLine, body: list[NumberedLine]):
    fields: dict[str, str] = {}
    field_lines: dict[str, int] = {}
    coefficients: list[float] = []
    for line in body:
        label, value = _compact_label(line)
        index = _COEFFICIENT_INDEX.match(label)
        if index:
            if int(index.group(1)) != len(coefficients):
                raise text.error(line.number, f"fit range {number}: coefficient C({index.group(1)}) out of "
                                              f"order (expected C({len(coefficients)}))")
            coefficients.append(text.number(leading_field(value), line.number,
                                            f"fit range {number}: C({len(coefficients)})"))
            continue
        key = next((key for prefix, key in RANGE_FIELDS if label.startswith(prefix)), None)
        if key is None:
            raise text.error(line.number, f"fit range {number}: unrecognised line {line.text.strip()!r}")
        if key in fields:
            raise text.error(line.number, f"fit range {number}: {FIELD_WORDS[key]} given twice "
                                          f"(first on line {field_lines[key]})")
        if coefficients:
            raise text.error(line.number, f"fit range {number}: {FIELD_WORDS[key]} after the coefficients")
        fields[key] = leading_field(value)
        field_lines[key] = line.number
    missing = [FIELD_WORDS[key] for _, key in RANGE_FIELDS if key not in fields]
    if missing:
        raise text.error(start.number, f"fit range {number} lacks {', '.join(missing)}")
    fit_type = fields["fit_type"].upper()
    if fit_type not in FIT_TYPES:
        raise text.error(field_lines["fit_type"], f"fit range {number}: fit type must be LOG or LIN, "
                                                  f"got {fields['fit_type']!r}")
    order = text.whole_number(fields["order"], field_lines["order"], f"fit range {number}: order")
    if len(coefficients) != order + 1:
        last = body[-1].number if body else start.number
        raise text.error(last, f"fit range {number}: order {order} needs {order + 1} coefficients "
                               f"C(0)..C({order}), found {len(coefficients)}")
    numbers = {key: text.number(fields[key], field_lines[key], f"fit range {number}: {FIELD_WORDS[key]}")
               for key in ("z_lower", "z_upper", "lower_limit", "upper_limit")}
    return ChebyshevFitRange(fit_type, numbers["z_lower"], numbers["z_upper"], numbers["lower_limit"],
                             numbers["upper_limit"], tuple(coefficients))
