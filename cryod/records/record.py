"""The data record, ``cryod-log v1``: what the daemon writes and the analysis reads.

Layout (UTF-8 text)::

    # cryod-log v1
    # key: value                  metadata: config snapshot, units, versions, ...
    time_s,T2_K,T5_K,heater_W,setpoint_K[,more columns]
    0.0800,4.2306589,3.256174,0.000000e+00,

* ``time_s``: seconds since the record started, at the row's trigger instant.
* ``T2_K``, ``T5_K``: flange and PTC-stage temperatures at that instant.
* ``heater_W``: heater power applied from this row until the next.
* ``setpoint_K``: control setpoint, empty when the loop is open.

Readers ignore columns they do not know, and refuse a record without a
required column, naming it. Comment lines (``# ...``) after the header are
events (faults, reloads) and are kept with the row they precede. A last line
cut short (a killed writer) is dropped with a warning; everything before it is
kept.

Examples
--------
>>> text = "# cryod-log v1\\n# site: lab 2\\ntime_s,T2_K,T5_K,heater_W,setpoint_K\\n0.08,4.23,3.34,0,\\n"
>>> record = read_record_text(text)
>>> record.metadata["site"], record.time_s.tolist(), bool(np.isnan(record.setpoint_K[0]))
('lab 2', [0.08], True)
"""

from __future__ import annotations

import contextlib
import functools
import gzip
import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from cryod.records.bounds import (
    MAX_COLUMNS,
    MAX_DATA_LINE_CHARACTERS,
    MAX_HEADER_CHARACTERS,
    MAX_HEADER_LINE_CHARACTERS,
    MAX_LINES,
    MAX_TEXT_CHARACTERS,
    NOT_A_RECORD,
    size_text,
)
from cryod.records.columns import REQUIRED, format_field
from cryod.records.data_lines import DataLineError, read_data_lines
from cryod.regular_files import NotARegularFile, open_regular_file, regular_file_status

MAGIC = "# cryod-log v1"
#: Names of the columns every record has, first and in this order (declared in :mod:`cryod.records.columns`).
REQUIRED_COLUMNS = tuple(column.name for column in REQUIRED)


class RecordFormatError(ValueError):
    """A record that cannot be read, with the file and line."""

    def __init__(self, source: str, line: int | None, reason: str):
        self.source = source
        self.line = line
        self.reason = reason
        super().__init__(f"{source}:{line}: {reason}" if line is not None else f"{source}: {reason}")


@dataclass
class Record:
    """A cryod-log record in memory.

    Attributes
    ----------
    metadata : dict of str to str
        Header ``key: value`` lines, in order.
    columns : dict of str to numpy.ndarray
        Every column; numeric ones as float arrays (empty fields are NaN),
        others as arrays of str.
    events : list of (int, str)
        Comment lines after the header, with the index of the row they precede.
    warnings : list of str
        What the reader passed over (a cut-short last line).
    source : str
        Where it was read from.
    """

    metadata: dict[str, str]
    columns: dict[str, np.ndarray]
    events: list[tuple[int, str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    source: str = ""

    @property
    def time_s(self) -> np.ndarray:
        return self.columns["time_s"]

    @property
    def flange_K(self) -> np.ndarray:
        """T2, the flange (control) thermometer."""
        return self.columns["T2_K"]

    @property
    def ptc_stage_K(self) -> np.ndarray:
        """T5, the PTC second-stage thermometer."""
        return self.columns["T5_K"]

    @property
    def heater_w(self) -> np.ndarray:
        return self.columns["heater_W"]

    @property
    def setpoint_K(self) -> np.ndarray:
        return self.columns["setpoint_K"]

    def __len__(self) -> int:
        return int(self.time_s.size)

    def metadata_number(self, key: str, default: float | None = None) -> float | None:
        """A metadata value as a number (leading number of the text, units after it allowed)."""
        text = self.metadata.get(key)
        if text is None:
            return default
        try:
            return float(text.split()[0])
        except (ValueError, IndexError):
            raise RecordFormatError(self.source, None, f"metadata '{key}' is not a number: {text!r}") from None

    def select(self, mask) -> "Record":
        """A record with only the rows where ``mask`` is true (metadata kept)."""
        mask = np.asarray(mask, dtype=bool)
        return Record(dict(self.metadata), {k: v[mask] for k, v in self.columns.items()},
                      [], list(self.warnings), self.source)


def read_record(path: str | Path, columns: Iterable[str] | None = None) -> Record:
    """Read a cryod-log v1 file.

    The data lines are read a chunk at a time into one float array per
    column (:mod:`cryod.records.data_lines`): memory holds the numbers, not
    the text, whatever the record's length. Only a regular file is read (a
    FIFO, a device, a socket or a directory is refused before it is opened:
    :mod:`cryod.regular_files`), and a file beyond the bounds of
    :mod:`cryod.records.bounds` is refused as it streams in.

    Parameters
    ----------
    path : str or pathlib.Path
    columns : iterable of str, optional
        Read only these columns besides the required ones (a name the record
        does not have is passed over); the others are skipped unconverted.
        None: every column.

    Returns
    -------
    Record

    Raises
    ------
    RecordFormatError
        Not a cryod-log v1 file, not a regular file, beyond a bound, a
        required column missing, a line with the wrong number of fields, or a
        bad value in a required column (file, line and column named).
    """
    path = Path(path)
    source = str(path)
    try:
        size = _text_size(path)
    except NotARegularFile as error:
        raise RecordFormatError(source, None, f"{error.reason}: a record must be a regular file") from None
    except FileNotFoundError:
        raise RecordFormatError(source, None, "file not found") from None
    except OSError as error:
        raise RecordFormatError(source, None, f"cannot read: {error}") from None
    if path.suffix != ".gz" and size is not None and size > MAX_TEXT_CHARACTERS:   # known unless compressed
        raise RecordFormatError(source, None, f"{size / 1e9:.1f} GB, more than the {size_text(MAX_TEXT_CHARACTERS)} "
                                              f"a record may have ({NOT_A_RECORD})")
    lines = _FileLines(path)
    try:
        record = _read_lines(lines.open, source, columns, size, open_header=lines.open_header)
    except UnicodeDecodeError:
        line, reason = _first_line_not_utf8(path)
        raise RecordFormatError(source, line, reason) from None
    except NotARegularFile as error:             # put in the record's place while it was being read
        raise RecordFormatError(source, None, f"{error.reason}: a record must be a regular file") from None
    except EOFError as error:
        raise RecordFormatError(source, None, f"cannot read: {error} (the compressed file is cut short)") from None
    except OSError as error:
        raise RecordFormatError(source, None, f"cannot read: {error}") from None
    record.warnings[:0] = lines.warnings
    return record


def _open_binary(path: Path, on_cut=None):
    """The file's bytes (decompressed for ``.csv.gz``: a finished day's record, :mod:`cryod.records.compression`)."""
    raw = open_regular_file(path)
    if path.suffix != ".gz":
        return raw
    try:
        return _RecordGzipFile(raw, on_cut)
    except BaseException:
        raw.close()
        raise


class _RecordGzipFile(gzip.GzipFile):
    """A compressed record: closes the file it reads from with itself and, given ``on_cut``, ends where a file
    cut short (a copy interrupted) ends, calling ``on_cut()``, so that the rows before the cut are kept."""

    def __init__(self, raw, on_cut=None):
        super().__init__(fileobj=raw, mode="rb")
        self._raw = raw
        self._on_cut = on_cut

    def _up_to_a_cut(self, read, *args):
        if self._on_cut is None:
            return read(*args)
        try:
            return read(*args)
        except EOFError:
            self._on_cut()
            return b""

    def read(self, size=-1):
        return self._up_to_a_cut(super().read, size)

    def read1(self, size=-1):
        return self._up_to_a_cut(super().read1, size)

    def close(self) -> None:
        try:
            super().close()
        finally:
            self._raw.close()


class _FileLines:
    """Opens a record file as text, each time from its start, gathering the warnings of a compressed file
    cut short."""

    CUT_SHORT = "the compressed file is cut short (it ends before its end marker): read up to the cut"

    def __init__(self, path: Path):
        self.path = path
        self.warnings: list[str] = []

    def open(self) -> io.TextIOWrapper:
        """The text, to the end or to a cut."""
        return io.TextIOWrapper(_open_binary(self.path, self._cut), encoding="utf-8")

    def open_header(self) -> io.TextIOWrapper:
        """The text for the header: a cut before its end is an error (EOFError)."""
        return io.TextIOWrapper(_open_binary(self.path), encoding="utf-8")

    def _cut(self) -> None:
        if self.CUT_SHORT not in self.warnings:
            self.warnings.append(self.CUT_SHORT)


def _text_size(path: Path) -> int | None:
    """Characters of text in the file, near enough to size the columns (None: not known); refuses a file that
    is not a regular file."""
    size = regular_file_status(path).st_size
    if path.suffix != ".gz":
        return size
    with open_regular_file(path) as stream:   # gzip's last four bytes: the text's length modulo 2**32
        stream.seek(max(size - 4, 0))
        stated = int.from_bytes(stream.read(4), "little")
    return stated if stated > size else None


def _first_line_not_utf8(path: Path) -> tuple[int | None, str]:
    """The first line of a file that is not UTF-8 text, and what is wrong with it (or the first line too long
    to look at)."""
    limit = MAX_HEADER_LINE_CHARACTERS
    try:
        with _open_binary(path) as stream:
            for number in range(1, MAX_LINES + 1):
                line = stream.readline(limit + 2)
                if not line:
                    break
                if len(line.rstrip(b"\r\n")) > limit:
                    return number, _too_long("line", limit)
                try:
                    line.decode("utf-8")
                except UnicodeDecodeError as error:
                    return number, (f"not UTF-8 text: byte 0x{line[error.start]:02x} at character {error.start + 1} "
                                    f"({NOT_A_RECORD})")
    except (OSError, EOFError, ValueError):
        pass
    return None, "not UTF-8 text"


def _too_long(what: str, limit: int) -> str:
    return f"{what} longer than {size_text(limit)}, the most a record's {what} may have ({NOT_A_RECORD})"


def read_record_text(text: str, source: str = "<record>", columns: Iterable[str] | None = None) -> Record:
    """Like :func:`read_record`, from text."""
    return _read_lines(lambda: io.StringIO(text, newline=None), source, columns, len(text))


def _read_lines(open_lines, source: str, columns: Iterable[str] | None, size: int | None,
                open_header=None) -> Record:
    wanted = None if columns is None else set(columns)
    with contextlib.closing((open_header or open_lines)()) as stream:
        metadata, names, header_line, header_characters = _read_header(stream, source)
    count = header_line

    def data_lines():
        stream = open_lines()
        try:
            for _ in range(count):
                stream.readline(MAX_HEADER_LINE_CHARACTERS + 1)
            yield from iter(functools.partial(stream.readline, MAX_DATA_LINE_CHARACTERS + 1), "")
        finally:
            stream.close()

    try:
        table = read_data_lines(data_lines, names, first_line_number=header_line + 1, wanted=wanted,
                                expected_characters=None if size is None else max(size - header_characters, 0),
                                characters_before=header_characters)
    except DataLineError as error:
        raise RecordFormatError(source, error.line, error.reason) from None
    return Record(metadata, table.columns, table.events, table.warnings, source)


def _read_header(stream, source: str) -> tuple[dict[str, str], list[str], int, int]:
    """Metadata, column names, the header's line number and the characters up to its end (each line read
    no further than the bounds allow)."""
    number, characters = 0, 0

    def next_line() -> str:
        nonlocal number, characters
        line = stream.readline(MAX_HEADER_LINE_CHARACTERS + 1)
        number += 1
        characters += len(line)
        if len(line.rstrip("\r\n")) > MAX_HEADER_LINE_CHARACTERS:
            raise RecordFormatError(source, number, _too_long("header line", MAX_HEADER_LINE_CHARACTERS))
        if characters > MAX_HEADER_CHARACTERS:
            raise RecordFormatError(source, number, f"the header goes on for more than "
                                                    f"{size_text(MAX_HEADER_CHARACTERS)}, the most a record's "
                                                    f"header may have ({NOT_A_RECORD})")
        return line

    first = next_line()
    if first.strip() != MAGIC:
        raise RecordFormatError(source, 1, f"not a cryod-log v1 record (first line should be '{MAGIC}', "
                                           f"got {first.rstrip(chr(10))[:60]!r})")
    metadata: dict[str, str] = {}
    while True:
        line = next_line()
        if not line:
            raise RecordFormatError(source, number, "no column header line after the metadata")
        if not line.startswith("#"):
            break
        body = line[1:].rstrip("\r\n")
        if ":" in body:
            key, value = body.split(":", 1)
            # "# key: value": drop the one separating space, keep any indentation after it
            key, value = key.strip(), (value[1:] if value.startswith(" ") else value).rstrip()
            # a multi-line value is written as repeated lines with the same key
            metadata[key] = f"{metadata[key]}\n{value}" if key in metadata else value
    names = [name.strip() for name in line.rstrip("\r\n").split(",")]
    if len(names) > MAX_COLUMNS:
        raise RecordFormatError(source, number, f"{len(names)} columns, more than the {MAX_COLUMNS} a record may "
                                                f"have ({NOT_A_RECORD})")
    for required in REQUIRED_COLUMNS:
        if required not in names:
            raise RecordFormatError(source, number, f"required column '{required}' is missing "
                                                    f"(columns: {', '.join(names)[:300]})")
    if len(set(names)) != len(names):
        raise RecordFormatError(source, number, "a column name appears twice")
    return metadata, names, number, characters


# ---------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------
def format_header(metadata: Mapping[str, object], columns: Iterable[str]) -> str:
    """Magic line, metadata lines and the column header, newline-terminated."""
    columns = list(columns)
    if list(columns[:len(REQUIRED_COLUMNS)]) != list(REQUIRED_COLUMNS):
        raise ValueError(f"the first columns must be {', '.join(REQUIRED_COLUMNS)}")
    lines = [MAGIC]
    for key, value in metadata.items():
        key = str(key)
        if ":" in key or "\n" in key:
            raise ValueError(f"metadata key {key!r} may not contain ':' or a newline")
        for part in str(value).splitlines() or [""]:
            lines.append(f"# {key}: {part}")
    lines.append(",".join(columns))
    return "\n".join(lines) + "\n"


def format_row(columns: Iterable[str], values: Mapping[str, object]) -> str:
    """One data line, newline-terminated."""
    return ",".join(format_field(name, values.get(name)) for name in columns) + "\n"


def write_record(path: str | Path, columns: Mapping[str, Iterable], metadata: Mapping[str, object] | None = None) -> Path:
    """Write a whole record at once (records made by tools and tests).

    Parameters
    ----------
    path : str or pathlib.Path
        New file; an existing file is never overwritten.
    columns : mapping of str to array_like
        At least the required columns, which come first in the file.
    metadata : mapping, optional

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    names = list(REQUIRED_COLUMNS) + [name for name in columns if name not in REQUIRED_COLUMNS]
    for required in REQUIRED_COLUMNS:
        if required not in columns:
            raise ValueError(f"required column '{required}' missing")
    arrays = {name: np.asarray(columns[name]) for name in names}
    length = {array.shape[0] for array in arrays.values()}
    if len(length) != 1:
        raise ValueError("all columns must have the same length")
    with path.open("x", encoding="utf-8") as stream:
        stream.write(format_header(metadata or {}, names))
        for row in range(length.pop()):
            stream.write(format_row(names, {name: _item(arrays[name][row]) for name in names}))
    return path


def _item(value):
    return value.item() if hasattr(value, "item") else value
