"""The data log: cryod-log v1 files written by a thread of their own.

Rows arrive through a queue (the loop never waits on a disk). Each row is
written and flushed to the operating system as soon as the writer takes it
(rows that queued up together share one flush); ``fsync`` runs at least
every ``fsync_interval_s`` (at most 2 s) and on rotation and stop. A process
killed with SIGKILL therefore loses at most the rows still in its queue (a few
ticks), a power cut at most the last ``fsync_interval_s``; a cut-short last
line is dropped by the reader and everything before it is kept.

One file per UTC day, ``cryod-YYYY-MM-DD.csv``, each a complete record with
its own header (``time_s`` counts from that file's start). An existing file
is never opened for writing again: a restart the same day writes
``cryod-YYYY-MM-DD.2.csv``, and so on. Files of finished days are compressed
to ``.csv.gz`` (:mod:`cryod.records.compression`).

A lab must not regulate unrecorded for hours. The free space of the data
directory is checked when a file opens and every ``FREE_SPACE_CHECK_ROWS``
rows (a minute in service): below ``warn_free_bytes`` a warning goes to the
journal and into the record (once, until the space is back); below
``min_free_bytes``, or when a write fails, ``on_failure`` is called with the
reason (the daemon then stops with the heater at 0 W, exit 7). Above the
minimum the writer still has room for the stop event and the last rows.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
import queue
import shutil
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable, Mapping

from cryod.records.columns import Event, Row, RowSchema
from cryod.records.compression import compress_in_background
from cryod.records.record import format_header

log = logging.getLogger("cryod.datalog")

_STOP = object()          # queued by stop(): write what came before, then close
#: Rows written per flush at most.
MAX_BATCH = 1000
#: After a batch of this many rows (the loop runs faster than real time), pause this long.
BATCH_PAUSE_AT = 50
BATCH_PAUSE_S = 0.05
#: Free space is checked every this many rows (a minute at 80 ms), and when a file opens.
FREE_SPACE_CHECK_ROWS = 750


def free_bytes(directory: Path) -> int:
    """Free space for an unprivileged writer in ``directory``'s file system (bytes)."""
    return shutil.disk_usage(directory).free


def _utc_text(wall_s: float) -> str:
    return dt.datetime.fromtimestamp(wall_s, dt.timezone.utc).isoformat(timespec="milliseconds")


def _event_line(event: Event) -> str:
    """An event as one comment line (a text of several lines joined, so no line escapes the ``#``)."""
    return f"# event: {' '.join(event.text.splitlines())}\n"


class DataLog:
    """Writes rows and events to daily cryod-log files.

    Parameters
    ----------
    directory : pathlib.Path
        Data directory (created if missing).
    schema : RowSchema
        The columns and how rows fill them.
    metadata : mapping
        Header lines (config snapshot, versions, units...).
    monotonic_to_wall : callable
        Converts a row's clock time (s) to wall time (s since the epoch), for
        the file's date and start time.
    period_s : float
        Loop period: a file's time origin is one period before its first row.
    fsync_interval_s : float
        Longest time between fsyncs while rows arrive (at most 2 s).
    warn_free_bytes, min_free_bytes : int
        Free space below which a warning is given, and below which ``on_failure`` is called.
    on_failure : callable, optional
        Called once, from the writer thread, with the reason when the log cannot go on (a failed
        write, too little space): the caller stops what must not run unrecorded.
    free_space : callable
        Free bytes of a directory (:func:`free_bytes`; tests give a fake disk).
    compress_finished : bool
        Compress the records of days before the one being written (:mod:`cryod.records.compression`)
        when a day's file opens.
    """

    def __init__(self, directory: Path, schema: RowSchema, metadata: Mapping[str, object],
                 monotonic_to_wall: Callable[[float], float], period_s: float, fsync_interval_s: float = 2.0, *,
                 warn_free_bytes: int = 0, min_free_bytes: int = 0,
                 on_failure: Callable[[str], None] | None = None,
                 free_space: Callable[[Path], int] = free_bytes, compress_finished: bool = False):
        self.directory = Path(directory)
        self.schema = schema
        self.metadata = dict(metadata)
        self.monotonic_to_wall = monotonic_to_wall
        self.period_s = period_s
        self.fsync_interval_s = min(fsync_interval_s, 2.0)
        self._queue: queue.SimpleQueue = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._stream = None
        self._day: str | None = None
        self._origin_s = 0.0
        self._last_fsync = 0.0
        self._dirty = False
        self.paths: list[Path] = []
        self.error: BaseException | None = None
        self._pending_events: list[Event] = []   # events before the first file is open
        self.warn_free_bytes = warn_free_bytes
        self.min_free_bytes = min_free_bytes
        self.on_failure = on_failure
        self.free_space = free_space
        self.failure: str | None = None          # why the log could not go on (on_failure was called with it)
        self._warned = False
        self._rows_since_check = 0
        self.compress_finished = compress_finished
        self._compressing: threading.Thread | None = None

    # -- producer side (any thread, never blocks) ------------------------------
    def put(self, item: Row | Event) -> None:
        """A row (``time_s`` in clock seconds) or an event, to be written in the order given."""
        self._queue.put(item)

    # -- lifetime -------------------------------------------------------------------
    def start(self) -> None:
        """Check that the data directory takes files and has room, then start the writer thread.

        A directory that cannot be written or is short of space is a failure (``on_failure``, and
        :attr:`failure` says why) before anything else happens: nothing is to run unrecorded.
        """
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=self.directory):
                pass
        except OSError as error:
            what = "is not a directory" if self.directory.exists() and not self.directory.is_dir() \
                else f"cannot be written ({type(error).__name__}: {error.strerror or error})"
            self._fail(f"data.directory {self.directory} {what}")
        else:
            self.check_free_space()
        self._thread = threading.Thread(target=self._run, name="cryod-datalog", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        """Write what is queued, fsync and close."""
        if self._thread is None:
            return
        self._queue.put(_STOP)
        self._thread.join(timeout_s)
        self._thread = None
        if self._compressing is not None:      # an interrupted compression is redone at the next start
            self._compressing.join(timeout_s)

    # -- writer thread -------------------------------------------------------------
    def _run(self) -> None:
        try:
            stopping = False
            while not stopping:
                try:
                    batch = [self._queue.get(timeout=self.fsync_interval_s / 2)]
                except queue.Empty:
                    self._sync_if_due(force=self._dirty)
                    continue
                # everything already queued goes out with one flush: in service that is one row per
                # period; when the loop runs faster than real time (--speed max) it saves a thread
                # switch per row
                while len(batch) < MAX_BATCH:
                    try:
                        batch.append(self._queue.get_nowait())
                    except queue.Empty:
                        break
                for item in batch:
                    match item:
                        case Row():
                            self._write_row(item)
                        case Event():
                            self._write_event(item)
                        case _ if item is _STOP:
                            stopping = True
                            if self._pending_events and self._stream is None and self.failure is None:
                                self._open_without_rows()
                            break
                        case _:
                            raise TypeError(f"the data log takes rows and events, not {type(item).__name__}")
                if self._stream is not None:
                    self._stream.flush()
                self._sync_if_due()
                if len(batch) >= BATCH_PAUSE_AT and not stopping:
                    time.sleep(BATCH_PAUSE_S)      # let rows gather instead of waking for each one
        except BaseException as error:          # a full disk must not go unnoticed
            self.error = error
            log.critical("data log stopped: %s", error)
            self._fail(f"writing {self._describe_target()} failed: {type(error).__name__}: {error}")
        finally:
            try:
                self._close()
            except OSError as error:            # the disk that failed the write may fail the close too
                log.critical("data log: closing the file failed: %s", error)

    def _write_row(self, row: Row) -> None:
        clock_time = row.time_s
        wall = self.monotonic_to_wall(clock_time)
        day = dt.datetime.fromtimestamp(wall, dt.timezone.utc).strftime("%Y-%m-%d")
        if day != self._day:
            self._open(day, clock_time - self.period_s)
        self._stream.write(self.schema.format_row(row, origin_s=self._origin_s))
        self._dirty = True
        self._rows_since_check += 1
        if self._rows_since_check >= FREE_SPACE_CHECK_ROWS:
            self.check_free_space()

    def _write_event(self, event: Event) -> None:
        if self._stream is None:
            self._pending_events.append(event)
            return
        self._stream.write(_event_line(event))
        self._dirty = True

    def _open_without_rows(self) -> None:
        """A run that stops before its first row (instruments never came, a signal while waiting) still
        leaves its events: a record of the header and those events, dated now."""
        wall = time.time()
        self._open(dt.datetime.fromtimestamp(wall, dt.timezone.utc).strftime("%Y-%m-%d"), 0.0, start_wall_s=wall)

    def _open(self, day: str, origin_s: float, start_wall_s: float | None = None) -> None:
        self._close()
        path = self._free_path(day)
        self._stream = path.open("x", encoding="utf-8", newline="\n")
        self._day = day
        self._origin_s = origin_s
        start_wall_s = self.monotonic_to_wall(origin_s) if start_wall_s is None else start_wall_s
        header = {"record_start_utc": _utc_text(start_wall_s), **self.metadata}
        self._stream.write(format_header(header, self.schema.names))
        for event in self._pending_events:
            self._stream.write(_event_line(event))
        self._pending_events.clear()
        self._stream.flush()
        self._sync()
        self.paths.append(path)
        log.info("data log: writing %s", path)
        self.check_free_space()
        if self.compress_finished and (self._compressing is None or not self._compressing.is_alive()):
            self._compressing = compress_in_background(self.directory, day)

    # -- free space --------------------------------------------------------------------
    def check_free_space(self) -> None:
        """Warn below ``warn_free_bytes``; below ``min_free_bytes`` report the failure (writer thread,
        or before the writer starts)."""
        self._rows_since_check = 0
        try:
            free = self.free_space(self.directory)
        except OSError as error:
            self._fail(f"the free space of {self.directory} cannot be read: {error}")
            return
        megabytes = free / 1e6
        if free < self.min_free_bytes:
            self._fail(f"only {megabytes:.0f} MB free for {self.directory}, below data.min_free_MB "
                       f"{self.min_free_bytes / 1e6:g} MB")
        elif free < self.warn_free_bytes:
            if not self._warned:
                self._warned = True
                text = (f"only {megabytes:.0f} MB free for {self.directory}, below data.warn_free_MB "
                        f"{self.warn_free_bytes / 1e6:g} MB: at data.min_free_MB {self.min_free_bytes / 1e6:g} MB "
                        f"cryod stops the heater and exits 7; free some space")
                log.warning("data log: %s", text)
                self._write_event(Event("disk", text))
        else:
            self._warned = False

    def _fail(self, reason: str) -> None:
        if self.failure is not None:
            return
        self.failure = reason
        log.critical("data log: %s", reason)
        if self._stream is not None:
            try:
                self._write_event(Event("disk", f"{reason}: stopping"))
            except OSError:
                pass
        if self.on_failure is not None:
            self.on_failure(reason)

    def _describe_target(self) -> str:
        return str(self.paths[-1]) if self.paths and self._stream is not None else str(self.directory)

    def _free_path(self, day: str) -> Path:
        candidate = self.directory / f"cryod-{day}.csv"
        number = 2
        while candidate.exists() or candidate.with_name(candidate.name + ".gz").exists():
            candidate = self.directory / f"cryod-{day}.{number}.csv"
            number += 1
        return candidate

    def _sync_if_due(self, force: bool = False) -> None:
        if self._stream is None or not self._dirty:
            return
        if force or time.monotonic() - self._last_fsync >= self.fsync_interval_s:
            self._sync()

    def _sync(self) -> None:
        os.fsync(self._stream.fileno())
        self._last_fsync = time.monotonic()
        self._dirty = False

    def _close(self) -> None:
        if self._stream is not None:
            self._stream.flush()
            self._sync()
            self._stream.close()
            self._stream = None
