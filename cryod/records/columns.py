"""The columns of the daemon's records, each declared once: name, unit, format and meaning.

The first five are the ``cryod-log v1`` contract (:data:`REQUIRED`); the loop
adds its measurement and timing columns; each control term declares its own
(:attr:`cryod.control.terms.ControlTerm.columns`). The data file's ``units``
header line is generated from these declarations.

Rows and events travel from the loop to the data log and the other listeners
as typed objects, :class:`Row` and :class:`Event`.

Examples
--------
>>> schema = RowSchema(REQUIRED + (STATE,))
>>> schema.names
('time_s', 'T2_K', 'T5_K', 'heater_W', 'setpoint_K', 'state')
>>> schema.format_row(Row(time_s=0.08, lateness_ms=0.1, state="holding", T2_K=4.2306589, T5_K=3.256174,
...                       heater_W=0.0))
'0.0800,4.2306589,3.256174,0.000000e+00,,holding\\n'
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from operator import attrgetter
from typing import Iterable, Sequence, final


@dataclass(frozen=True)
class Column:
    """One column of a record.

    Attributes
    ----------
    name : str
        Header name; ends with the unit (``_K``, ``_W``, ``_ohm``, ``_ms``, ``_s``) where it has one.
    unit : str
        Unit, or ``""`` for text.
    description : str
        What the value is, for the header's units line and the docs.
    format : str, optional
        ``str.format`` pattern; None writes a number's shortest exact form and text as it is.
    is_time : bool
        A clock time: written as seconds since the record start, like ``time_s``.
    """

    name: str
    unit: str
    description: str
    format: str | None = None
    is_time: bool = False

    def formatted(self, value) -> str:
        """The field text: None and NaN are empty; text may not contain ',' or a newline."""
        if value is None:
            return ""
        if isinstance(value, str):
            if "," in value or "\n" in value:
                raise ValueError(f"column {self.name!r}: text may not contain ',' or a newline")
            return value
        value = float(value)
        if math.isnan(value):
            return ""
        return self.format.format(value) if self.format else repr(value)

    def describe(self) -> str:
        """``name [unit]: description``."""
        return f"{self.name} [{self.unit}]: {self.description}" if self.unit else f"{self.name}: {self.description}"


# -- the cryod-log v1 contract -------------------------------------------------
#: Digits of ``time_s`` after the point: rows must lie further apart than 10**-TIME_DECIMALS s, or they
#: would print as one instant (the records' times strictly increase).
TIME_DECIMALS = 4
TIME = Column("time_s", "s", "since the record start, at the row's trigger instant (monotonic clock); a row of "
                             "its own at the instant the supply confirmed a heater-off", f"{{:.{TIME_DECIMALS}f}}",
              is_time=True)
FLANGE_TEMPERATURE = Column("T2_K", "K", "flange (control) thermometer", "{:.7f}")
PTC_STAGE_TEMPERATURE = Column("T5_K", "K", "PTC second-stage thermometer", "{:.6f}")
HEATER_POWER = Column("heater_W", "W", "heater power applied from this row until the next", "{:.6e}")
SETPOINT = Column("setpoint_K", "K", "control setpoint, empty when the loop is open", "{:.7f}")
#: Columns every record has, first and in this order.
REQUIRED = (TIME, FLANGE_TEMPERATURE, PTC_STAGE_TEMPERATURE, HEATER_POWER, SETPOINT)

# -- what the loop adds ----------------------------------------------------------
FLANGE_RESISTANCE = Column("T2_ohm", "ohm", "flange Cernox resistance")
PTC_STAGE_RESISTANCE = Column("T5_ohm", "ohm", "PTC-stage Cernox resistance")
FLANGE_SAMPLE_TIME = Column("T2_sample_s", "s", "since the record start, the instant T2 stands for: the middle of "
                                              "its reading's A/D conversions", "{:.5f}", is_time=True)
PTC_STAGE_SAMPLE_TIME = Column("T5_sample_s", "s", "since the record start, the instant T5 stands for",
                               "{:.5f}", is_time=True)
HEATER_SET_TIME = Column("heater_set_s", "s", "since the record start, when this row's heater power was set "
                                             "(the supply's write returned)", "{:.5f}", is_time=True)
TRIGGER_SKEW = Column("trigger_skew_ms", "ms", "PTC-stage trigger minus flange trigger (0: simultaneous)", "{:.3f}")
LATENESS = Column("lateness_ms", "ms", "tick start after its deadline (empty on a heater-off's own row: not a tick)",
                  "{:.2f}")
CYCLE = Column("cycle_ms", "ms", "tick start to row", "{:.2f}")
STATE = Column("state", "", "loop state: holding, closed, closed-limited (heater at a limit), manual, off, "
                            "recovering, fault:<cause>")
#: The loop's columns before the control terms' and after them.
LOOP_MEASUREMENT = (FLANGE_RESISTANCE, PTC_STAGE_RESISTANCE, FLANGE_SAMPLE_TIME, PTC_STAGE_SAMPLE_TIME,
                    HEATER_SET_TIME, TRIGGER_SKEW, LATENESS, CYCLE)
LOOP_END = (STATE,)

_REQUIRED_BY_NAME = {column.name: column for column in REQUIRED}


def format_field(name: str, value) -> str:
    """A field of a column known only by name (records written by tools): required columns
    in their fixed format, any other number in its shortest exact form."""
    column = _REQUIRED_BY_NAME.get(name)
    return (column or Column(name, "", "")).formatted(value)


@final         # the loop's listeners tell a row from an event by type(item) is Row
@dataclass(slots=True)
class Row:
    """One tick's row, as the loop hands it to the data log and the other listeners.

    Numbers are NaN (written empty) where the tick did not get that far;
    ``control`` holds the control terms' columns by name.
    """

    time_s: float
    lateness_ms: float
    state: str = ""
    T2_K: float = math.nan
    T5_K: float = math.nan
    heater_W: float = math.nan
    setpoint_K: float = math.nan
    T2_ohm: float = math.nan
    T5_ohm: float = math.nan
    T2_sample_s: float = math.nan
    T5_sample_s: float = math.nan
    heater_set_s: float = math.nan
    trigger_skew_ms: float = math.nan
    cycle_ms: float = math.nan
    control: dict[str, float] = field(default_factory=dict)

    def value(self, name: str):
        """The value of a column by name (NaN if this row has none)."""
        if name in self.control:
            return self.control[name]
        return getattr(self, name, math.nan)


@dataclass(frozen=True, slots=True)
class Event:
    """Something that happened, written to the data file as a ``# event: kind: message`` line.

    Attributes
    ----------
    kind : str
        ``fault``, ``stop``, ``resumed``, ``overrun``, ``command``, ``reload`` ...
    message : str
    details : dict, optional
        The figures behind the message, for listeners that act on them (an alarm's change for the lab's
        hook); not written to the record.
    """

    kind: str
    message: str
    details: dict | None = field(default=None, compare=False)

    @property
    def text(self) -> str:
        return f"{self.kind}: {self.message}"

    def __str__(self) -> str:
        return self.text


class RowSchema:
    """The ordered columns of a data file and how a :class:`Row` fills them.

    Parameters
    ----------
    columns : sequence of Column
        Starting with :data:`REQUIRED`.
    """

    def __init__(self, columns: Sequence[Column]):
        self.columns = tuple(columns)
        self.names = tuple(column.name for column in self.columns)
        if self.names[:len(REQUIRED)] != tuple(column.name for column in REQUIRED):
            raise ValueError(f"the first columns must be {', '.join(column.name for column in REQUIRED)}")
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"a column is declared twice in {', '.join(self.names)}")
        row_fields = set(Row.__slots__)
        # (name, on the Row itself, a clock time, its format's bound method or None, what formats a float), for
        # the field-by-field path
        self._plan = [(column.name, column.name in row_fields, column.is_time,
                       column.format.format if column.format else None,
                       column.format.format if column.format else float.__repr__) for column in self.columns]
        self._line = _LinePattern(self.columns, row_fields)

    def format_row(self, row: Row, origin_s: float = 0.0) -> str:
        """One data line, newline-terminated, with the clock times counted from ``origin_s``.

        The same text as :meth:`Column.formatted` of each field (a test holds them to it). A row
        of floats, text and empty fields, as the loop makes them, is written with one
        ``%``-pattern (:class:`_LinePattern`); any other field by field.
        """
        line = self._line.formatted(row, origin_s)
        return line if line is not None else self._field_by_field(row, origin_s)

    def _field_by_field(self, row: Row, origin_s: float) -> str:
        control = row.control
        fields: list[str] = []
        append = fields.append
        for name, on_row, is_time, pattern, float_format in self._plan:
            value = getattr(row, name) if on_row else control.get(name)
            if value is None or value != value:          # missing or NaN: empty
                append("")
            elif value.__class__ is float:               # most fields: the same text as below, fewer steps
                append(float_format(value - origin_s if is_time else value))
            elif isinstance(value, str):
                if "," in value or "\n" in value:
                    raise ValueError(f"column {name!r}: text may not contain ',' or a newline")
                append(value)
            else:
                value = float(value) - origin_s if is_time else float(value)
                append(pattern(value) if pattern else repr(value))
        return ",".join(fields) + "\n"

    def units_text(self) -> str:
        """The header's ``units`` line: every column's unit and meaning."""
        return "; ".join(column.describe() for column in self.columns)


#: ``str.format`` patterns of one float that ``%``-formatting writes to the same text (the same conversion).
_PERCENT_FORMAT = re.compile(r"\{:(\.\d+[ef])\}")
#: What ``%s`` and the float conversions write for a missing (None) or NaN field, which the record leaves empty.
_EMPTY_FIELD_TEXTS = ("nan", "None")


class _LinePattern:
    """A data line in one ``%``-formatting: the text :meth:`RowSchema.format_row` writes field by field.

    The values are fetched in runs of neighbouring columns (on the :class:`Row` itself through one
    :func:`operator.attrgetter`, or in its ``control`` dict), clock times counted from the origin, and
    formatted together by one pattern: ``%.7f`` for ``{:.7f}`` (the same conversion), ``%s`` for a
    column without a format (a float's ``str`` is its ``repr``); fields that come out as ``nan`` or
    ``None`` are left empty. :meth:`formatted` gives None for what it cannot write so (a value of
    another type, a missing control value of a formatted column, text with a comma or a newline or
    that reads ``nan``), which the field-by-field path then writes or refuses.
    """

    def __init__(self, columns: Sequence[Column], row_fields: set[str]):
        specs = [_percent_spec(column) for column in columns]
        self.pattern = ",".join(spec for spec in specs if spec is not None) if None not in specs else None
        self.field_count = len(columns)
        self.time_at = tuple(index for index, column in enumerate(columns) if column.is_time)
        self.text_at = tuple(index for index, column in enumerate(columns) if column.format is None)
        self.runs: list[tuple[bool, tuple[str, ...], attrgetter | None]] = []     # (on the Row, names, getter)
        for column in columns:
            on_row = column.name in row_fields
            if self.runs and self.runs[-1][0] == on_row:
                names = self.runs[-1][1] + (column.name,)
                self.runs[-1] = (on_row, names, attrgetter(*names) if on_row and len(names) > 1 else None)
            else:
                self.runs.append((on_row, (column.name,), None))

    def formatted(self, row: Row, origin_s: float) -> str | None:
        """The data line of ``row``, newline-terminated; None when it is not a row of floats, text and empty fields."""
        if self.pattern is None:
            return None
        values: list = []
        control = row.control
        for on_row, names, getter in self.runs:
            if not on_row:
                values.extend(map(control.get, names))
            elif getter is not None:
                values.extend(getter(row))
            else:
                values.append(getattr(row, names[0]))
        for index in self.time_at:
            value = values[index]
            if value.__class__ is not float:
                return None
            values[index] = value - origin_s
        for index in self.text_at:
            value = values[index]
            if value.__class__ is float or value is None:
                continue
            if not isinstance(value, str) or value in _EMPTY_FIELD_TEXTS:
                return None
            values[index] = str.__str__(value)       # a str subclass (a state) as its characters, as join writes it
        try:
            text = self.pattern % tuple(values)
        except TypeError:                            # a formatted column without a number
            return None
        fields = text.split(",")
        if len(fields) != self.field_count or "\n" in text:
            return None                              # a comma or a newline in a text: refused field by field
        return ",".join(["" if field in _EMPTY_FIELD_TEXTS else field for field in fields]) + "\n"


def _percent_spec(column: Column) -> str | None:
    """The ``%``-conversion that writes ``column``'s floats as its format does; None where there is none."""
    if column.format is None:
        return "%s"
    simple = _PERCENT_FORMAT.fullmatch(column.format)
    return "%" + simple.group(1) if simple else None


def loop_schema(control_columns: Iterable[Column]) -> RowSchema:
    """The daemon's columns: the contract, the loop's measurement and timing, the control terms', the state."""
    return RowSchema(REQUIRED + LOOP_MEASUREMENT + tuple(control_columns) + LOOP_END)
