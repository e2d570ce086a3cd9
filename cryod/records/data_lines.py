"""The data lines of a ``cryod-log v1`` record, read in chunks into one array per column.

A day of records is about 300 MB of text and 2 million rows. The lines are
taken a chunk at a time (:data:`CHUNK_ROWS`) and each wanted column is
converted straight into a float array allocated once for the whole record
(its length estimated from the size of the text, grown if the estimate was
short), so memory holds the numbers, one chunk of text and nothing per row.
Columns not wanted are skipped without being converted.

What is checked, with the line named: the field count of every line, the
required columns' numbers, ``time_s`` present and increasing. Comment lines are
events, kept with the index of the row they precede. A last line without its
newline (a writer killed mid-line) that does not parse is dropped with a
warning. A column that is not all numbers is read as text (a second pass over
the lines for that column alone, if the first non-number comes after the
first chunk).

Examples
--------
>>> lines = ["0.08,4.23,3.34,0,,ok\\n", "# event: fault\\n", "0.16,4.24,3.35,1e-3,5.0,ok"]
>>> table = read_data_lines(lambda: iter(lines), ["time_s", "T2_K", "T5_K", "heater_W", "setpoint_K", "state"],
...                         first_line_number=3)
>>> table.columns["setpoint_K"].tolist(), table.columns["state"].tolist(), table.events
([nan, 5.0], ['ok', 'ok'], [(1, 'event: fault')])
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Callable, Collection, Iterator

import numpy as np

from cryod.records.bounds import (
    MAX_DATA_LINE_CHARACTERS,
    MAX_EVENT_CHARACTERS,
    MAX_LINES,
    MAX_TEXT_CHARACTERS,
    NOT_A_RECORD,
    size_text,
)
from cryod.records.columns import REQUIRED

#: Lines converted at a time: about 300 kB of daemon text, 4 MB while split into fields.
CHUNK_ROWS = 1024
#: Names of the columns every record has (see :mod:`cryod.records.columns`).
REQUIRED_NAMES = tuple(column.name for column in REQUIRED)


class DataLineError(ValueError):
    """A data line that cannot be read: its line number and what is wrong."""

    def __init__(self, line: int, reason: str):
        self.line = line
        self.reason = reason
        super().__init__(f"line {line}: {reason}")


@dataclass
class DataTable:
    """The columns, events and warnings of a record's data lines.

    Attributes
    ----------
    columns : dict of str to numpy.ndarray
        Float arrays (empty fields NaN) and, for columns that are not all
        numbers, arrays of str; in the header's order.
    events : list of (int, str)
        Comment lines with the index of the row they precede.
    warnings : list of str
        What was passed over (a cut-short last line).
    """

    columns: dict[str, np.ndarray]
    events: list[tuple[int, str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


class _TextColumn(Exception):
    """A column first thought numeric holds text: read again with it as text."""

    def __init__(self, name: str):
        self.name = name


class _GrowingArray:
    """A float array filled chunk by chunk, allocated once from an estimate of the length."""

    def __init__(self, capacity: int):
        self.array = np.empty(max(capacity, 1))
        self.size = 0

    def extend(self, values) -> None:
        end = self.size + len(values)
        if end > self.array.size:
            self.array.resize(max(end, int(self.array.size * 1.5)), refcheck=False)
        self.array[self.size:end] = values
        self.size = end

    def finish(self) -> np.ndarray:
        self.array.resize(self.size, refcheck=False)
        return self.array


def read_data_lines(open_lines: Callable[[], Iterator[str]], names: list[str], *, first_line_number: int,
                    wanted: Collection[str] | None = None, expected_characters: int | None = None,
                    characters_before: int = 0) -> DataTable:
    """Read the data lines of a record into columns.

    Parameters
    ----------
    open_lines : callable
        Returns an iterator over the lines after the column header, each with
        its newline except perhaps the last. Called again only if a column
        turns out to be text after its first chunk.
    names : list of str
        The column header's names.
    first_line_number : int
        File line number of the first data line (for messages).
    wanted : collection of str, optional
        Columns to read (the required ones are always read); None: all.
    expected_characters : int, optional
        Length of the text of the data lines, to size the arrays at once.
    characters_before : int
        Characters of the file before the first data line (the header), counted
        against :data:`~cryod.records.bounds.MAX_TEXT_CHARACTERS`.

    Returns
    -------
    DataTable

    Raises
    ------
    DataLineError
        A line with the wrong number of fields, a required column that is
        not a number, ``time_s`` empty or not increasing; a line, the lines,
        the text or the events beyond the bounds of :mod:`cryod.records.bounds`
        (the lines are expected no longer than one character past
        :data:`~cryod.records.bounds.MAX_DATA_LINE_CHARACTERS`, as
        ``readline(MAX_DATA_LINE_CHARACTERS + 1)`` gives them, so that a
        longer one is refused without being held whole).
    """
    text_columns: set[str] = set()
    while True:
        try:
            return _read(open_lines(), names, first_line_number, wanted, expected_characters, text_columns,
                         characters_before)
        except _TextColumn as again:
            text_columns.add(again.name)


def _read(lines: Iterator[str], names, first_line_number, wanted, expected_characters, text_columns,
          characters_before) -> DataTable:
    count = len(names)
    selected = [(position, name) for position, name in enumerate(names)
                if wanted is None or name in REQUIRED_NAMES or name in wanted]
    numbers: dict[str, _GrowingArray] = {}
    texts: dict[str, list[str]] = {name: [] for _, name in selected if name in text_columns}
    events: list[tuple[int, str]] = []
    warnings: list[str] = []
    rows = 0
    previous_time = -math.inf
    line_number = first_line_number
    bounds = _Bounds(characters_before)
    while True:
        chunk = list(itertools.islice(lines, CHUNK_ROWS))
        if not chunk:
            break
        bounds.check(chunk, line_number)
        if chunk.count("\n") == len(chunk):          # blank lines only (a padded or damaged file): nothing to sort
            line_number += len(chunk)
            continue
        known_events = len(events)
        data, data_lines = _sort_lines(chunk, line_number, count, rows, events, warnings)
        bounds.check_events(events[known_events:], line_number + len(chunk) - 1)
        line_number += len(chunk)
        # a last line without its newline: a killed writer's, perhaps cut inside a number
        unterminated = bool(data) and not chunk[-1].endswith("\n") and data_lines[-1] == line_number - 1
        while data:
            fields = ",".join(data).split(",")
            try:
                converted = _convert(fields, count, selected, texts)
                break
            except _NotANumber as bad:
                last = bad.index == len(data) - 1
                if unterminated and last and (bad.name in REQUIRED_NAMES or rows + len(data) > 1):
                    warnings.append(f"line {data_lines[-1]}: last line cut short, dropped")
                    data.pop()
                    data_lines.pop()
                    unterminated = False
                    continue
                if bad.name in REQUIRED_NAMES:
                    raise DataLineError(data_lines[bad.index],
                                        f"column '{bad.name}': not a number: {bad.text!r}") from None
                if rows > 0:
                    raise _TextColumn(bad.name) from None
                texts[bad.name] = []
        if not data:
            continue
        time_s = converted["time_s"]
        _check_time(time_s, previous_time, data_lines)
        previous_time = float(time_s[-1])
        for position, name in selected:
            if name in texts:
                texts[name].extend(item.strip() for item in fields[position::count])
            else:
                if name not in numbers:
                    numbers[name] = _GrowingArray(_estimated_rows(data, expected_characters))
                numbers[name].extend(converted[name])
        rows += len(data)
    columns: dict[str, np.ndarray] = {}
    for _, name in selected:
        if name in texts:
            columns[name] = np.array(texts[name], dtype=str)
        elif name in numbers:
            columns[name] = numbers[name].finish()
        else:
            columns[name] = np.empty(0)
    return DataTable(columns, events, warnings)


class _Bounds:
    """The bounds of :mod:`cryod.records.bounds` on the lines after the header, checked a chunk at a time."""

    def __init__(self, characters_before: int):
        self.characters = characters_before
        self.event_characters = 0

    def check(self, chunk: list[str], first_line: int) -> None:
        last_line = first_line + len(chunk) - 1
        if last_line > MAX_LINES:
            raise DataLineError(MAX_LINES + 1, f"more than {MAX_LINES} lines, the most a record may have (a 7-day "
                                               f"record at 80 ms has 7.6 million; {NOT_A_RECORD})")
        longest = max(map(len, chunk))
        if longest > MAX_DATA_LINE_CHARACTERS:
            index = next(i for i, line in enumerate(chunk) if len(line) > MAX_DATA_LINE_CHARACTERS)
            if len(chunk[index].rstrip("\r\n")) > MAX_DATA_LINE_CHARACTERS:
                raise DataLineError(first_line + index, f"longer than {size_text(MAX_DATA_LINE_CHARACTERS)}, the "
                                                        f"most a line after a record's header may have (a row is a "
                                                        f"few hundred characters; {NOT_A_RECORD})")
        self.characters += sum(map(len, chunk))
        if self.characters > MAX_TEXT_CHARACTERS:
            raise DataLineError(last_line, f"the text goes on for more than {size_text(MAX_TEXT_CHARACTERS)}, the "
                                           f"most a record may have ({NOT_A_RECORD})")

    def check_events(self, new_events: list[tuple[int, str]], last_line: int) -> None:
        self.event_characters += sum(len(text) for _, text in new_events)
        if self.event_characters > MAX_EVENT_CHARACTERS:
            raise DataLineError(last_line, f"more than {size_text(MAX_EVENT_CHARACTERS)} of event lines, the most "
                                           f"a record may have ({NOT_A_RECORD})")


def _sort_lines(chunk: list[str], line_number: int, count: int, rows: int, events: list, warnings: list):
    """The chunk's data lines (newline taken off) and their line numbers; events and a cut-short
    last line go to ``events`` and ``warnings``, blank lines nowhere."""
    data: list[str] = []
    data_lines: list[int] = []
    for offset, line in enumerate(chunk):
        number = line_number + offset
        terminated = line.endswith("\n")
        line = line.rstrip("\r\n")
        if not line.strip():
            continue
        if line.startswith("#"):
            events.append((rows + len(data), line[1:].strip()))
            continue
        if line.count(",") != count - 1:
            if not terminated:
                warnings.append(f"line {number}: last line cut short, dropped")
                continue
            raise DataLineError(number, f"expected {count} fields (the header's columns), got {line.count(',') + 1}")
        data.append(line)
        data_lines.append(number)
    return data, data_lines


class _NotANumber(Exception):
    def __init__(self, name: str, index: int, text: str):
        self.name, self.index, self.text = name, index, text


def _convert(fields: list[str], count: int, selected, texts) -> dict[str, np.ndarray]:
    """The chunk's numeric columns as float arrays; raises _NotANumber at the first field that is not one."""
    converted = {}
    for position, name in selected:
        if name in texts:
            continue
        strings = fields[position::count]
        values, bad = _numbers(strings)
        if bad is not None:
            raise _NotANumber(name, bad, strings[bad].strip())
        assert values is not None           # _numbers gives the array whenever every field is a number
        converted[name] = values
    return converted


def _estimated_rows(data: list[str], expected_characters: int | None) -> int:
    """Rows the whole record will have, from the first chunk's line length."""
    if not expected_characters:
        return len(data)
    per_row = (sum(len(line) for line in data) + len(data)) / len(data)
    return min(int(expected_characters / per_row * 1.02) + len(data), MAX_LINES)


def _numbers(strings: list[str]) -> tuple[np.ndarray | None, int | None]:
    """Float array of the fields (empty: NaN), or (None, index of the first field that is not a number)."""
    nan = math.nan
    try:
        return np.array([float(item) if item else nan for item in strings]), None
    except ValueError:
        pass
    values = np.empty(len(strings))
    for index, item in enumerate(strings):
        item = item.strip()
        try:
            values[index] = float(item) if item else nan
        except ValueError:
            return None, index
    return values, None


def _check_time(time_s: np.ndarray, previous_s: float, lines: list[int]) -> None:
    if np.isnan(time_s).any():
        bad = int(np.flatnonzero(np.isnan(time_s))[0])
        raise DataLineError(lines[bad], "column 'time_s': empty")
    steps = np.diff(time_s, prepend=previous_s)
    if np.any(steps <= 0.0):
        bad = int(np.flatnonzero(steps <= 0.0)[0])
        raise DataLineError(lines[bad], "column 'time_s': time does not increase")


__all__ = ["CHUNK_ROWS", "DataLineError", "DataTable", "read_data_lines"]
