"""Finished daily records are compressed: ``cryod-YYYY-MM-DD.csv`` becomes ``.csv.gz``.

A record takes about 10 MB an hour (240 MB a day with the feedforward's
columns) as text and about a fifth of that compressed. A day's file is
finished once the UTC day is over (the data log never writes a file again once
it is closed, and a new day starts a new file), so files of earlier days are
compressed, on a thread of their own, when the daemon starts and when the
data log moves to a new day. The compressed file is written beside the text
under a temporary name, synced, renamed, and only then is the text removed: a
crash at any point leaves the text file or both, never neither. The readers
(:func:`cryod.read_record`, pandas, numpy) take the ``.csv.gz`` files as they are.

Examples
--------
>>> finished_day("cryod-2026-11-22.2.csv", "2026-11-23"), finished_day("cryod-2026-11-23.csv", "2026-11-23")
(True, False)
"""

from __future__ import annotations

import gzip
import logging
import os
import re
import shutil
import threading
from pathlib import Path

log = logging.getLogger("cryod.datalog")

_DAILY = re.compile(r"cryod-(\d{4}-\d{2}-\d{2})(\.\d+)?\.csv")
#: Suffix of a compressed file while it is being written.
PARTIAL = ".gz.partial"


def finished_day(name: str, today: str) -> bool:
    """True for a daily record's file name (``cryod-YYYY-MM-DD[.N].csv``) of a day before ``today``."""
    match = _DAILY.fullmatch(name)
    return match is not None and match.group(1) < today


def where_now(path: Path) -> Path:
    """Where a record written at ``path`` is now: ``path`` itself, or its ``.gz`` once its day was compressed.

    A run's summary names every record it wrote; a run across UTC midnight finds the first day's
    file compressed by the time it ends.
    """
    compressed = path.with_name(path.name + ".gz")
    return compressed if not path.exists() and compressed.exists() else path


def compress_file(path: Path) -> Path:
    """Compress one finished record to ``path.gz`` (temporary name, fsync, rename), then remove ``path``."""
    path = Path(path)
    target = path.with_name(path.name + ".gz")
    partial = path.with_name(path.name + PARTIAL)
    with path.open("rb") as source, gzip.open(partial, "wb", compresslevel=6) as sink:
        shutil.copyfileobj(source, sink, length=1 << 20)
    with partial.open("rb") as written:
        os.fsync(written.fileno())
    os.replace(partial, target)
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)                   # the rename is on disk before the text goes
    finally:
        os.close(directory)
    path.unlink()
    return target


def record_path_now(path: Path) -> Path:
    """Where a record written as ``path`` is now: its ``.csv.gz`` once its finished day was compressed."""
    path = Path(path)
    compressed = path.with_name(path.name + ".gz")
    return compressed if not path.exists() and compressed.exists() else path


def compress_finished(directory: Path, today: str) -> list[Path]:
    """Compress every finished daily record in ``directory`` (days before ``today``); the new files.

    A failure (a full disk, say) is logged, the text file is kept, and the rest go on.
    """
    directory = Path(directory)
    written = []
    for stale in directory.glob(f"cryod-*.csv{PARTIAL}"):       # a compression a crash interrupted
        stale.unlink(missing_ok=True)
    for path in sorted(directory.glob("cryod-*.csv")):
        if not finished_day(path.name, today):
            continue
        if path.with_name(path.name + ".gz").exists():
            log.warning("data log: %s and %s.gz both exist; keeping both", path, path.name)
            continue
        try:
            written.append(compress_file(path))
        except OSError as error:
            path.with_name(path.name + PARTIAL).unlink(missing_ok=True)
            log.error("data log: compressing %s failed, the text file is kept: %s", path, error)
            continue
        log.info("data log: compressed the finished record %s", written[-1])
    return written


def compress_in_background(directory: Path, today: str, after: threading.Thread | None = None) -> threading.Thread:
    """Run :func:`compress_finished` on a daemon thread; returns the thread.

    ``after``, a compression still running (a day that ended while the one before was being
    compressed), is waited for first, so that every finished day is compressed in turn and none is
    left for the next start.
    """
    def compress_in_turn() -> None:
        if after is not None:
            after.join()
        compress_finished(directory, today)

    thread = threading.Thread(target=compress_in_turn, name="cryod-compress", daemon=True)
    thread.start()
    return thread
