"""Files that are not records, or records beyond every bound: what the readers and tools must refuse.

Each maker writes its file under ``folder`` (or names a special file) and returns the path to hand to a
reader. ``HOSTILE_RECORDS`` lists the adversarial run's cases (tests/test_hostile_records.py, slow, and
benchmarks/hostile_records.py) with what the outcome must mention; the sizes are those of the attacks
they stand for (a 300 MB header line, a 1 MB gzip of 1 GiB of blank lines).
"""

from __future__ import annotations

import gzip
import os
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

HEADER = "# cryod-log v1\ntime_s,T2_K,T5_K,heater_W,setpoint_K\n"
ROW = "0.0800,4.2306589,3.256174,0.000000e+00,\n"


def _write_repeated(stream, character, count: int) -> None:
    """``count`` times ``character`` into ``stream``, a MiB at a time."""
    block = character * (1 << 20)
    for _ in range(count // len(block)):
        stream.write(block)
    stream.write(character * (count % len(block)))


def fifo(folder: Path) -> Path:
    path = folder / "fifo.csv"
    os.mkfifo(path)
    return path


def dev_zero(folder: Path) -> Path:
    return Path("/dev/zero")


def directory(folder: Path) -> Path:
    path = folder / "directory.csv"
    path.mkdir()
    return path


def unix_socket(folder: Path) -> Path:
    path = folder / "socket.csv"
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(path))
    listener.close()                      # the socket file stays
    return path


def long_header_line(folder: Path, characters: int = 300_000_000) -> Path:
    """A metadata line of ``characters``, then a valid column header and one row."""
    path = folder / "long-header-line.csv"
    with path.open("w", encoding="ascii") as stream:
        stream.write("# cryod-log v1\n# site: ")
        _write_repeated(stream, "a", characters)
        stream.write("\ntime_s,T2_K,T5_K,heater_W,setpoint_K\n" + ROW)
    return path


def long_data_line(folder: Path, characters: int = 300_000_000) -> Path:
    """A valid header, then one line of ``characters`` digits without a comma."""
    path = folder / "long-data-line.csv"
    with path.open("w", encoding="ascii") as stream:
        stream.write(HEADER)
        _write_repeated(stream, "1", characters)
        stream.write("\n")
    return path


def many_columns(folder: Path, count: int = 100_000) -> Path:
    path = folder / "many-columns.csv"
    names = ",".join(f"c{index}" for index in range(count))
    path.write_text(f"# cryod-log v1\ntime_s,T2_K,T5_K,heater_W,setpoint_K,{names}\n", encoding="ascii")
    return path


def gzip_of_blank_lines(folder: Path, blank_bytes: int = 1 << 30) -> Path:
    """A valid header and row, then ``blank_bytes`` newlines, compressed (1 GiB: about 1 MB of gzip)."""
    path = folder / "blank-lines.csv.gz"
    with gzip.open(path, "wb", compresslevel=9) as stream:
        stream.write((HEADER + ROW).encode())
        _write_repeated(stream, b"\n", blank_bytes)
    return path


def gzip_of_one_line(folder: Path, line_bytes: int = 1 << 30) -> Path:
    """A valid header, then one line of ``line_bytes`` digits, compressed."""
    path = folder / "one-line.csv.gz"
    with gzip.open(path, "wb", compresslevel=9) as stream:
        stream.write(HEADER.encode())
        _write_repeated(stream, b"1", line_bytes)
    return path


def too_many_lines(folder: Path, lines: int = 20_000_001) -> Path:
    """A valid header and row, then blank lines: more lines than a record may have, in 20 MB."""
    path = folder / "too-many-lines.csv"
    with path.open("w", encoding="ascii") as stream:
        stream.write(HEADER + ROW)
        _write_repeated(stream, "\n", lines)
    return path


def sparse_file(folder: Path, size: int = 9 << 30) -> Path:
    """A hole of ``size`` bytes (NUL characters to a reader, no disk used)."""
    path = folder / "sparse.csv"
    with path.open("wb") as stream:
        stream.truncate(size)
    return path


def binary_garbage(folder: Path, size: int = 10 << 20) -> Path:
    path = folder / "garbage.csv"
    path.write_bytes(os.urandom(size))
    return path


def truncated_gzip(folder: Path, rows: int = 20_000) -> Path:
    """A record of ``rows`` rows, compressed, cut in the middle (a copy interrupted)."""
    path = folder / "truncated.csv.gz"
    text = HEADER + "".join(f"{0.08 * (index + 1):.4f},4.2306589,3.256174,0.000000e+00,\n" for index in range(rows))
    compressed = gzip.compress(text.encode())
    path.write_bytes(compressed[:len(compressed) // 2])
    return path


def utf16_record(folder: Path) -> Path:
    path = folder / "utf16.csv"
    path.write_bytes((HEADER + ROW).encode("utf-16"))
    return path


def latin1_record(folder: Path) -> Path:
    path = folder / "latin1.csv"
    path.write_bytes(("# cryod-log v1\n# site: Laboratoire de cryogénie\n" + HEADER.split("\n", 1)[1] + ROW)
                     .encode("latin-1"))
    return path


@dataclass(frozen=True)
class HostileRecord:
    """One case of the adversarial run: how to make it and what the refusal (or warning) must say."""

    name: str
    make: Callable[[Path], Path]
    says: str
    read: bool = False        # read, with a warning, rather than refused


HOSTILE_RECORDS = (
    HostileRecord("FIFO", fifo, "is a FIFO (named pipe), not a regular file"),
    HostileRecord("/dev/zero", dev_zero, "is a character device"),
    HostileRecord("directory", directory, "is a directory, not a regular file"),
    HostileRecord("socket", unix_socket, "is a socket, not a regular file"),
    HostileRecord("300 MB header line", long_header_line, ":2: header line longer than 1 MiB"),
    HostileRecord("300 MB data line", long_data_line, ":3: longer than 64 KiB"),
    HostileRecord("100 000 columns", many_columns, "100005 columns, more than the 1000"),
    HostileRecord("1 MB gzip of 1 GiB blank lines", gzip_of_blank_lines, ":20000001: more than 20000000 lines"),
    HostileRecord("1 MB gzip of one 1 GiB line", gzip_of_one_line, ":3: longer than 64 KiB"),
    HostileRecord("20 000 001 lines", too_many_lines, ":20000001: more than 20000000 lines"),
    HostileRecord("9 GiB sparse file", sparse_file, "more than the 8 GiB a record may have"),
    HostileRecord("10 MB of random bytes", binary_garbage, "not UTF-8 text"),
    HostileRecord("truncated gzip", truncated_gzip, "the compressed file is cut short", read=True),
    HostileRecord("UTF-16 record", utf16_record, ":1: not UTF-8 text: byte 0xff"),
    HostileRecord("Latin-1 record", latin1_record, ":2: not UTF-8 text: byte 0xe9"),
)
