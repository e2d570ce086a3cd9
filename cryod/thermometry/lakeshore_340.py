"""Reading Lake Shore ``.340`` curve files.

Layout (Lake Shore, "Model 8000 option: disk storage of sensor calibration
data, file description", the 340 CalCurve file; "the readable listing" of a
curve for the Model 340 and later controllers)::

    Sensor Model:   CX-1050-SD-HT-1.4L
    Serial Number:  X186279
    Data Format:    4      (Log Ohms/Kelvin)
    SetPoint Limit: 325.0      (Kelvin)
    Temperature coefficient:  1 (Negative)
    Number of Breakpoints:   149

    No.   Units      Temperature (K)

      1  1.82643       330.010
      2  1.83215       325.000

Header labels are matched without regard to case or spacing; the value is the
first field after the colon (a parenthesised comment may follow). Every header
line is required; only the sensor model and serial number may be blank (a
user-made curve). Breakpoints are numbered 1, 2, ... and there must be as many
as the header announces, so a truncated file is refused. Sensor units and
temperatures must be strictly monotonic, and their trend must agree with the
header's temperature coefficient (1 = negative: the reading falls as the
temperature rises; 2 = positive), as the Model 340 manual's CRVHDR command
defines it. Errors name the file and the line.
"""

from __future__ import annotations

from cryod.thermometry.breakpoints import DATA_FORMATS, BreakpointCurve, DataFormat
from cryod.thermometry.source_text import CalibrationText, NumberedLine, label_and_value, leading_field

#: The header fields, by normalised label, with the attribute each fills.
HEADER_LABELS = {
    "sensor model": "sensor_model",
    "serial number": "serial_number",
    "data format": "data_format",
    "setpoint limit": "setpoint_limit_K",
    "temperature coefficient": "temperature_coefficient",
    "number of breakpoints": "breakpoint_count",
}
#: The header labels as Lake Shore writes them, by attribute (for messages).
HEADER_TITLES = {"sensor_model": "Sensor Model", "serial_number": "Serial Number", "data_format": "Data Format",
                 "setpoint_limit_K": "SetPoint Limit", "temperature_coefficient": "Temperature coefficient",
                 "breakpoint_count": "Number of Breakpoints"}
_EXPECTED_HEADER = f"a .340 header has {', '.join(HEADER_TITLES.values())}"
TEMPERATURE_COEFFICIENTS = {1: "negative", 2: "positive"}
_FORMAT_LIST = ", ".join(f"{code} = {fmt.name}" for code, fmt in DATA_FORMATS.items())


def read_340(text: CalibrationText) -> BreakpointCurve:
    """Parse a ``.340`` file into a :class:`BreakpointCurve`.

    Raises
    ------
    CalibrationFileError
        A header field missing, repeated, unknown or invalid; a breakpoint
        line with the wrong number of fields or out of sequence; sensor units
        or temperatures not strictly monotonic; a trend that contradicts the
        temperature coefficient; fewer or more breakpoints than announced.
    """
    lines = text.content_lines()
    header, header_lines, position = _read_header(text, lines)
    if position < len(lines) and not _starts_with_number(lines[position].text):
        position += 1                                   # the "No.  Units  Temperature (K)" title line
    end_of_header = lines[position - 1].number if position else 1
    missing = [title for key, title in HEADER_TITLES.items() if key not in header]
    if missing:
        raise text.error(end_of_header, f"the header lacks {', '.join(map(repr, missing))} ({_EXPECTED_HEADER})")
    data_format = _data_format(text, header, header_lines)
    coefficient = _choice(text, header, header_lines, "temperature_coefficient", TEMPERATURE_COEFFICIENTS)
    setpoint_limit_K = text.number(header["setpoint_limit_K"], header_lines["setpoint_limit_K"], "setpoint limit")
    count = text.whole_number(header["breakpoint_count"], header_lines["breakpoint_count"], "number of breakpoints")
    if count < 2:
        raise text.error(header_lines["breakpoint_count"], f"a curve needs at least 2 breakpoints, header says {count}")
    units, temperatures, data_lines = _read_breakpoints(text, lines[position:], count,
                                                        header_lines["breakpoint_count"], data_format)
    for values, what in ((units, "sensor units"), (temperatures, "temperature")):
        _require_strictly_monotonic(text, values, data_lines, what)
    falls = (units[-1] - units[0]) * (temperatures[-1] - temperatures[0]) < 0.0
    if falls != (coefficient == 1):
        trend = "fall" if falls else "rise"
        raise text.error(header_lines["temperature_coefficient"],
                         f"temperature coefficient {coefficient} ({TEMPERATURE_COEFFICIENTS[coefficient]}) "
                         f"contradicts the breakpoints, whose sensor units {trend} as the temperature rises")
    return BreakpointCurve(units, temperatures, data_format, source=text.source,
                           sensor_model=header["sensor_model"], serial_number=header["serial_number"],
                           setpoint_limit_K=setpoint_limit_K)


def _read_header(text: CalibrationText, lines: list[NumberedLine]):
    header: dict[str, str | None] = {}
    header_lines: dict[str, int] = {}
    position = 0
    while position < len(lines) and ":" in lines[position].text:
        line = lines[position]
        label, value = label_and_value(line.text)
        key = HEADER_LABELS.get(label)
        if key is None:
            raise text.error(line.number, f"unknown header line {line.text.strip()!r} ({_EXPECTED_HEADER})")
        if key in header:
            raise text.error(line.number, f"{HEADER_TITLES[key]!r} given twice (first on line {header_lines[key]})")
        if key in ("sensor_model", "serial_number"):
            header[key] = value or None                 # a user-made curve may leave these blank
        elif not value:
            raise text.error(line.number, f"{HEADER_TITLES[key]!r} has no value")
        else:
            header[key] = leading_field(value)
        header_lines[key] = line.number
        position += 1
    return header, header_lines, position


def _data_format(text: CalibrationText, header, header_lines):
    return DATA_FORMATS[_choice(text, header, header_lines, "data_format", DATA_FORMATS, _FORMAT_LIST)]


def _choice(text: CalibrationText, header, header_lines, key: str, choices, described: str | None = None) -> int:
    line = header_lines[key]
    what = next(label for label, attribute in HEADER_LABELS.items() if attribute == key)
    code = text.whole_number(header[key], line, what)
    if code not in choices:
        described = described or ", ".join(f"{c} = {name}" for c, name in choices.items())
        raise text.error(line, f"{what} {code} is not one Lake Shore defines ({described})")
    return code


def _read_breakpoints(text: CalibrationText, lines: list[NumberedLine], count: int, count_line: int,
                      data_format: DataFormat):
    units: list[float] = []
    temperatures: list[float] = []
    data_lines: list[int] = []
    for line in lines:
        fields = line.text.split()
        expected = len(units) + 1
        if expected > count:
            raise text.error(line.number, f"more breakpoints than the {count} the header announces "
                                          f"(line {count_line})")
        if len(fields) != 3:
            raise text.error(line.number, f"breakpoint {expected}: expected 3 fields (number, units, "
                                          f"temperature), got {len(fields)}")
        number = text.whole_number(fields[0], line.number, f"breakpoint {expected}: number")
        if number != expected:
            raise text.error(line.number, f"breakpoint number {number} out of sequence (expected {expected})")
        value = text.number(fields[1], line.number, f"breakpoint {expected}: units")
        temperature = text.number(fields[2], line.number, f"breakpoint {expected}: temperature")
        if temperature <= 0.0:
            raise text.error(line.number, f"breakpoint {expected}: temperature must be above 0 K, got {temperature:g}")
        if data_format.code == 3 and value <= 0.0:
            raise text.error(line.number, f"breakpoint {expected}: resistance must be above 0 ohm, got {value:g}")
        units.append(value)
        temperatures.append(temperature)
        data_lines.append(line.number)
    if len(units) < count:
        raise text.error(text.last_line_number, f"the file ends after {len(units)} of the {count} breakpoints "
                                                f"the header announces (line {count_line}): truncated?")
    return units, temperatures, data_lines


def _require_strictly_monotonic(text: CalibrationText, values: list[float], data_lines: list[int], what: str):
    rising = values[1] > values[0]
    for index in range(1, len(values)):
        step = values[index] - values[index - 1]
        if step == 0.0 or (step > 0.0) != rising:
            trend = "rising" if rising else "falling"
            raise text.error(data_lines[index], f"breakpoint {index + 1}: {what} {values[index]:g} break the "
                                                f"{trend} order of breakpoints 1 to {index} "
                                                f"(previous {values[index - 1]:g}); breakpoints must be strictly "
                                                f"monotonic")


def _starts_with_number(line: str) -> bool:
    fields = line.split()
    try:
        float(fields[0])
    except (IndexError, ValueError):
        return False
    return True
