"""A calibration file as numbered lines, and errors that point at one of them.

Lake Shore files come from Windows as often as not: lines may end in CRLF (or
LF, or a lone CR); all are accepted. A UTF-8 byte-order mark is ignored.

Examples
--------
>>> text = CalibrationText("Sensor Model:   CX-1050\\r\\nData Format:    4  (Log Ohms/Kelvin)\\r\\n", "X1.340")
>>> [(line.number, line.text) for line in text.lines]
[(1, 'Sensor Model:   CX-1050'), (2, 'Data Format:    4  (Log Ohms/Kelvin)')]
>>> label_and_value(text.lines[1].text)
('data format', '4  (Log Ohms/Kelvin)')
>>> text.number("4.0e1", 2, "temperature")
40.0
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from cryod.regular_files import NotARegularFile, open_regular_file
from cryod.thermometry.errors import CalibrationFileError

_SPACES = re.compile(r"\s+")
#: Largest calibration file read (bytes): a .340 curve of 200 points is 6 kB, a raw table of thousands
#: of points a few hundred kB.
MAX_FILE_BYTES = 10_000_000


@dataclass(frozen=True)
class NumberedLine:
    """One line of a file, without its line ending; ``number`` is 1-based."""

    number: int
    text: str


class CalibrationText:
    """The lines of one calibration file, with located errors.

    Parameters
    ----------
    text : str
        File content.
    source : str
        File name, used in every error message.
    """

    def __init__(self, text: str, source: str):
        self.source = source
        if text.startswith("\ufeff"):
            text = text[1:]
        self.lines = [NumberedLine(number, line) for number, line in enumerate(text.splitlines(), start=1)]

    @classmethod
    def read(cls, path: str | Path) -> "CalibrationText":
        """Read a file; a missing, unreadable or binary file is a :class:`CalibrationFileError`."""
        path = Path(path)
        try:
            with open_regular_file(path) as stream:
                raw = stream.read(MAX_FILE_BYTES + 1)
        except FileNotFoundError:
            raise CalibrationFileError(str(path), None, "file not found") from None
        except NotARegularFile as error:
            raise CalibrationFileError(str(path), None, error.reason) from None
        except OSError as error:
            raise CalibrationFileError(str(path), None, f"cannot read: {error.strerror or error}") from None
        if len(raw) > MAX_FILE_BYTES:
            raise CalibrationFileError(str(path), None, f"larger than {MAX_FILE_BYTES} bytes: not a calibration file")
        if b"\0" in raw:
            raise CalibrationFileError(str(path), None, "not a text file (contains NUL bytes)")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")      # vendor files are ASCII; a stray degree sign is not fatal
        return cls(text, str(path))

    def content_lines(self) -> list[NumberedLine]:
        """The lines that are not blank."""
        return [line for line in self.lines if line.text.strip()]

    @property
    def last_line_number(self) -> int:
        return self.lines[-1].number if self.lines else 1

    def error(self, line: int | None, reason: str) -> CalibrationFileError:
        """An error located at ``line`` of this file."""
        return CalibrationFileError(self.source, line, reason)

    def number(self, field: str, line: int, what: str) -> float:
        """``field`` as a finite float, or an error naming ``what`` and the line."""
        try:
            value = float(field)
        except ValueError:
            raise self.error(line, f"{what}: not a number: {field!r}") from None
        if not math.isfinite(value):
            raise self.error(line, f"{what}: must be finite, got {field!r}")
        return value

    def whole_number(self, field: str, line: int, what: str) -> int:
        """``field`` as an integer ('4', '4.0' and '4.' accepted), or a located error."""
        value = self.number(field, line, what)
        if value != int(value):
            raise self.error(line, f"{what}: must be a whole number, got {field!r}")
        return int(value)


def label_and_value(text: str) -> tuple[str, str]:
    """Split ``'Label:  value'`` into a normalised label (lower case, single spaces) and the value.

    A line without a colon gives an empty value and the whole line as label.
    """
    label, _, value = text.partition(":")
    return _SPACES.sub(" ", label.strip()).lower(), value.strip()


def leading_field(value: str) -> str:
    """The first whitespace-separated field of a header value (``'4  (Log Ohms/Kelvin)'`` gives ``'4'``)."""
    fields = value.split()
    return fields[0] if fields else ""
