"""The data log: cryod-log v1 files written by a thread of their own.

Rows arrive through a queue (the loop never waits on a disk). The rows and
events the writer takes together go out in one write as soon as it takes
them; ``fsync`` runs at least every ``fsync_interval_s`` (at most 2 s) and on
rotation and stop. A process killed with SIGKILL therefore loses at most the
rows still in its queue (a few ticks), a power cut at most the last
``fsync_interval_s``; a cut-short last line is dropped by the reader and
everything before it is kept.

One file per UTC day, ``cryod-YYYY-MM-DD.csv``, each a complete record with
its own header (``time_s`` counts from that file's start). An existing file
is never opened for writing: a restart the same day writes
``cryod-YYYY-MM-DD.2.csv``, and so on. Files of finished days are compressed
to ``.csv.gz`` (:mod:`cryod.records.compression`).

A lab must neither regulate unrecorded nor lose what it recorded:

* **Free space.** The data directory's free space is checked when a file
  opens, then at least every :data:`DISK_CHECK_INTERVAL_S` of the rows' clock
  (of real time while no rows come), and sooner while it falls fast: the next
  check comes before the free space, falling as fast as it did since the last
  check (the log's own rows and whatever else writes there), has lost
  1/:data:`FREE_SPACE_SHARE` of the room left above ``min_free_bytes``, down to
  a check at every write. Below ``warn_free_bytes``
  a warning goes to the journal and into the record (once, until the space is
  back); below ``min_free_bytes`` ``on_failure`` is called with the reason (the
  daemon then stops with the heater at 0 W, exit 7).
* **Room for the stop.** The file being written holds the disk space of its
  next :data:`~cryod.records.record_file.RESERVE_BYTES`
  (:mod:`cryod.records.record_file`), taken again when half of it is used.
  When the disk has no room to take it again (another program filled it),
  ``on_failure`` is called while the space still held takes the last rows and
  the stop event; from then on rows go in only while
  :data:`EVENT_ROOM_BYTES` of it stay free for the events, and rows left out
  are counted in an event.
* **The file itself.** Before each write the open file is looked at (deleted,
  or written by someone else), and its path at each disk check (renamed, or
  replaced by another file). The record then goes on in a new file (the next
  free name: never an existing file), with a ``disk`` event in the new file,
  in the old one while it is still there and unchanged, and in the journal;
  rows written into a deleted file since the last look are written again into
  the new one. A data directory that is gone (deleted or moved) is a failure,
  found within a write or a disk check.
* **Failed writes.** A write that fails anyway (an I/O error, a file size
  limit) is cut back to where it began, so no line is left half written and
  none before it is touched, and ``on_failure`` is called.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
import queue
import shutil
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable, Mapping

from cryod.records.columns import Event, Row, RowSchema
from cryod.records.compression import compress_in_background, where_now
from cryod.records.record import format_header
from cryod.records.record_file import RESERVE_BYTES, RecordFile

log = logging.getLogger("cryod.datalog")

_STOP = object()          # queued by stop(): write what came before, then close
#: Rows written per write at most.
MAX_BATCH = 1000
#: After a batch of this many rows (the loop runs faster than real time), pause this long.
BATCH_PAUSE_AT = 50
BATCH_PAUSE_S = 0.05
#: Woken again this soon (real time, s) after the last wake, the writer pauses too: rows come faster than real
#: time, and waking it for each one (a system call in the loop's put, then the two threads taking turns at the
#: interpreter lock) would cost the loop more than writing them. In service rows come a period apart.
QUICK_WAKE_S = 0.01
SECONDS_PER_DAY = 86400.0
#: Longest time between two checks of the free space and of the file's path (s).
DISK_CHECK_INTERVAL_S = 1.0
#: The next check comes before the free space, falling at the rate last seen, loses 1/FREE_SPACE_SHARE of the room
#: left above the minimum.
FREE_SPACE_SHARE = 8
#: Space held for events once the log has failed: rows stop going in before it is used.
EVENT_ROOM_BYTES = 64 << 10


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
        write, too little space, the data directory gone): the caller stops what must not run unrecorded.
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
        self._file: RecordFile | None = None
        self._day: str | None = None
        self._origin_s = 0.0
        self._last_fsync = 0.0
        self._dirty = False
        self.paths: list[Path] = []
        self.error: BaseException | None = None
        self._pending: list[Row | Event] = []       # taken, not yet written (events wait here for the first file)
        self._last_written: list[Row | Event] = []  # written since the file was last found as it should be
        self._last_row_s: float | None = None
        self._moved = False                      # the file went with its directory: kept to the end
        self.warn_free_bytes = warn_free_bytes
        self.min_free_bytes = min_free_bytes
        self.on_failure = on_failure
        self.free_space = free_space
        self.failure: str | None = None          # why the log could not go on (on_failure was called with it)
        self._warned = False
        self._last_disk_check = time.monotonic()       # real time, for the checks while no rows come
        self._next_check_s = -float("inf")              # clock time (the rows') of the next check
        self._last_free: tuple[float, int] | None = None   # (clock time, free bytes) at the last check
        self._left_out: list[float] = []         # clock times of rows not written (no room, no file)
        self._last_day: tuple[float, float, str] = (math.inf, -math.inf, "")   # see _utc_day
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

    def drain(self, timeout_s: float = 10.0) -> bool:
        """Wait until everything put before this call is written to the file (written, not yet synced).

        Returns
        -------
        bool
            False when the writer did not get there within ``timeout_s``.
        """
        written = threading.Event()
        self._queue.put(written)
        return written.wait(timeout_s)

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
    def written_paths(self) -> list[Path]:
        """Every record this log wrote, where each is now (a finished day's as its ``.csv.gz``)."""
        return [where_now(path) for path in self.paths]

    def _run(self) -> None:
        try:
            stopping = False
            woken_s = -float("inf")
            while not stopping:
                try:
                    batch = [self._queue.get(timeout=self.fsync_interval_s / 2)]
                except queue.Empty:
                    if time.monotonic() - self._last_disk_check >= DISK_CHECK_INTERVAL_S:
                        self._check_disk()
                    self._sync_if_due(force=self._dirty)
                    continue
                previous_wake_s, woken_s = woken_s, time.monotonic()
                # everything already queued goes out with one write: in service that is one row per
                # period; when the loop runs faster than real time (--speed max) it saves a thread
                # switch per row
                while len(batch) < MAX_BATCH:
                    try:
                        batch.append(self._queue.get_nowait())
                    except queue.Empty:
                        break
                for item in batch:
                    if item is _STOP:
                        stopping = True
                        if self._pending and self._day is None and self.failure is None:
                            self._open_without_rows()
                        break
                    if isinstance(item, threading.Event):      # drain(): what came before is written
                        self._write_pending()
                        item.set()
                        continue
                    self._take(item)
                self._write_pending()
                self._sync_if_due()
                if not stopping and (len(batch) >= BATCH_PAUSE_AT or woken_s - previous_wake_s < QUICK_WAKE_S):
                    time.sleep(BATCH_PAUSE_S)      # let rows gather instead of waking for each one
            self._look_at_file(at_path=True)   # rows in a file deleted just before the stop are not lost
        except BaseException as error:          # a bug: the log must not stop unnoticed
            self.error = error
            log.critical("data log stopped: %s", error)
            self._fail(f"writing {self._describe_target()} failed: {type(error).__name__}: {error}")
        finally:
            try:
                self._write_pending()
            except Exception as error:           # already failing: say so and close
                log.critical("data log: the last rows could not be written: %s", error)
            self._close()

    def _take(self, item: Row | Event) -> None:
        match item:
            case Row():
                day = self._utc_day(self.monotonic_to_wall(item.time_s))
                if day != self._day:
                    self._write_pending()
                    self._open(day, item.time_s - self.period_s)
                elif item.time_s >= self._next_check_s:      # what came before is written, then checked
                    self._write_pending()
                    self._check_disk()
                if self._file is None:
                    self._left_out.append(item.time_s)
                    return
                self._last_row_s = item.time_s
                self._pending.append(item)
            case Event():
                self._pending.append(item)
            case _:
                raise TypeError(f"the data log takes rows and events, not {type(item).__name__}")

    def _utc_day(self, wall_s: float) -> str:
        """The UTC date (``YYYY-MM-DD``) of ``wall_s`` (s since the epoch); the last one's kept with the span of
        wall times certainly in it (a millisecond inside its midnights, where rounding cannot move a time)."""
        low, high, day = self._last_day
        if low <= wall_s < high:
            return day
        day = dt.datetime.fromtimestamp(wall_s, dt.timezone.utc).strftime("%Y-%m-%d")
        midnight = math.floor(wall_s / SECONDS_PER_DAY) * SECONDS_PER_DAY
        if dt.datetime.fromtimestamp(midnight, dt.timezone.utc).strftime("%Y-%m-%d") == day:
            self._last_day = (midnight + 1e-3, midnight + SECONDS_PER_DAY - 1e-3, day)
        return day

    def _write_pending(self) -> None:
        """Write what was taken into the current file, after a look at the file."""
        if self._file is None or not self._pending:
            return
        self._look_at_file(at_path=False)
        record_file = self._file
        if record_file is None:
            self._left_out += [item.time_s for item in self._pending if isinstance(item, Row)]
            self._pending = [item for item in self._pending if isinstance(item, Event)]
            return
        items, self._pending = self._pending, []
        data = self._text(items, record_file)
        try:
            record_file.write(data)
        except OSError as error:            # nothing of it is in the file: the events are tried again
            self.error = error
            self._left_out += [item.time_s for item in items if isinstance(item, Row)]
            self._pending[:0] = [item for item in items if isinstance(item, Event)]
            self._fail(f"writing {record_file.path} failed: {error.strerror or error}")
            return
        self._dirty = True
        self._last_written = items
        self._hold_room(record_file)

    def _text(self, items: list[Row | Event], record_file: RecordFile) -> bytes:
        """The lines of ``items`` for ``record_file``; once the log has failed, rows only while the space held
        keeps :data:`EVENT_ROOM_BYTES` for the events, and an event about the rows left out before the next
        event."""
        room = record_file.room_held if self.failure is not None else None
        lines, used = [], 0
        for item in items:
            if isinstance(item, Event):
                if self._left_out:
                    lines.append(_event_line(self._left_out_event()))
                line = _event_line(item)
            else:
                line = self.schema.format_row(item, origin_s=self._origin_s)
                if room is not None and room - used - len(line) < EVENT_ROOM_BYTES:
                    self._left_out.append(item.time_s)
                    continue
            lines.append(line)
            used += len(line)
        return "".join(lines).encode("utf-8")

    def _left_out_event(self) -> Event:
        first, last, count = self._left_out[0], self._left_out[-1], len(self._left_out)
        self._left_out = []
        return Event("disk", f"{count} row(s) from clock time {first:.4f} s to {last:.4f} s could not be written "
                             f"({self.failure or 'no file to write them to'})")

    def _hold_room(self, record_file: RecordFile) -> None:
        """Take the space held ahead in ``record_file`` again once half of it is used; no room for it is a
        failure."""
        room = record_file.room_held
        if room is None or room >= RESERVE_BYTES // 2:
            return
        try:
            record_file.reserve()
        except OSError as error:
            self._fail(f"the disk of {self.directory} is full ({error.strerror or error}): no room left to "
                       f"hold for the record")

    # -- files ---------------------------------------------------------------------
    def _open_without_rows(self) -> None:
        """A run that stops before its first row (instruments never came, a signal while waiting) still
        leaves its events: a record of the header and those events, dated now."""
        wall = time.time()
        self._open(dt.datetime.fromtimestamp(wall, dt.timezone.utc).strftime("%Y-%m-%d"), 0.0, start_wall_s=wall)

    def _open(self, day: str, origin_s: float, start_wall_s: float | None = None) -> None:
        """Start the day's file (the one before is closed)."""
        self._close()
        self._day = day
        record_file = self._file = self._new_file(day)
        if record_file is None:
            return
        self._start_file(record_file, origin_s, start_wall_s)
        if self.compress_finished:
            running = self._compressing if self._compressing is not None and self._compressing.is_alive() else None
            self._compressing = compress_in_background(self.directory, day, after=running)

    def _new_file(self, day: str) -> RecordFile | None:
        """A file of a free name for ``day``; None (and the failure reported) when none can be made."""
        number = 1
        while True:
            name = f"cryod-{day}.csv" if number == 1 else f"cryod-{day}.{number}.csv"
            path = self.directory / name
            number += 1
            if path in self.paths or path.exists() or path.with_name(name + ".gz").exists():
                continue
            try:
                return RecordFile(path)
            except FileExistsError:            # made by someone else just now
                continue
            except OSError as error:
                gone = not self.directory.is_dir()
                self._fail(f"data.directory {self.directory} " + ("is gone (deleted or moved)" if gone else
                           f"takes no new file ({error.strerror or error})"))
                return None

    def _start_file(self, record_file: RecordFile, origin_s: float, start_wall_s: float | None = None) -> None:
        """Write the header of the new file ``record_file``, hold room after it, and check the free space."""
        self._origin_s = origin_s
        start_wall_s = self.monotonic_to_wall(origin_s) if start_wall_s is None else start_wall_s
        header = {"record_start_utc": _utc_text(start_wall_s), **self.metadata}
        try:
            record_file.write(format_header(header, self.schema.names).encode("utf-8"))
            record_file.sync()
            record_file.reserve()
        except OSError as error:
            self.error = error
            self._fail(f"starting {record_file.path} failed: {error.strerror or error}")
        self._last_fsync = time.monotonic()
        self._last_written = []
        self.paths.append(record_file.path)
        log.info("data log: writing %s", record_file.path.absolute())
        self.check_free_space()

    def _look_at_file(self, at_path: bool) -> None:
        """Find what others did to the file; a file deleted, moved, replaced or written by someone else is
        left for a new one."""
        record_file = self._file
        if record_file is None:
            return
        try:
            problem = record_file.check(at_path and not self._moved)
        except OSError as error:
            problem = f"out of reach ({error.strerror or error})"
        if problem is not None:
            self._go_on_in_new_file(record_file, problem)

    def _go_on_in_new_file(self, old: RecordFile, problem: str) -> None:
        """Leave ``old``, the file being written, for a new one of the same day."""
        kept = old.still_ours
        again = [] if kept else self._last_written        # rows only the deleted or overwritten file had
        day = self._day
        assert day is not None          # _open names the day before it opens the day's first file
        new_file = self._file = self._new_file(day)
        if new_file is None:
            if kept:                   # moved with its directory: the last rows and the stop still go in
                self._file, self._moved = old, True
                return
            log.critical("data log: %s was %s and no new file can be made", old.path, problem)
            self._close_file(old)
            return
        if kept:
            try:
                old.write(_event_line(Event("disk", f"this file was {problem}; the record goes on in "
                                                    f"{new_file.path.name}")).encode("utf-8"))
            except OSError:
                pass
        self._close_file(old)
        rows = [item.time_s for item in again + self._pending if isinstance(item, Row)]
        origin = rows[0] - self.period_s if rows else (self._last_row_s or self._origin_s)
        self._start_file(new_file, origin)
        repeated = sum(isinstance(item, Row) for item in again)
        text = (f"the record's file {old.path} was {problem}; it goes on in this file, time_s counted from "
                f"this file's start" + (f", beginning with the {repeated} row(s) written into that file after "
                                       f"it was last found in place" if repeated else ""))
        log.warning("data log: %s", text)
        self._pending[:0] = [Event("disk", text), *again]

    def _close_file(self, record_file: RecordFile) -> None:
        try:
            record_file.close()
        except OSError as error:           # the disk that failed a write may fail the close too
            log.critical("data log: closing %s failed: %s", record_file.path, error)

    def _close(self) -> None:
        if self._file is not None:
            if self._left_out:
                self._pending.append(self._left_out_event())
                self._write_pending()
            self._close_file(self._file)
            self._file = None

    # -- disk checks -------------------------------------------------------------------
    def _check_disk(self) -> None:
        """Look at the file's path and the free space; write what that adds (a new file's event, a warning)."""
        self._look_at_file(at_path=True)
        self.check_free_space()
        self._write_pending()                 # a new file's event, a warning

    def check_free_space(self) -> None:
        """Warn below ``warn_free_bytes``; below ``min_free_bytes`` report the failure (writer thread,
        or before the writer starts). Sets when the next check is due (on the rows' clock)."""
        self._last_disk_check = time.monotonic()
        try:
            free = self.free_space(self.directory)
        except OSError as error:
            gone = not self.directory.is_dir()
            self._fail(f"data.directory {self.directory} is gone (deleted or moved)" if gone else
                       f"the free space of {self.directory} cannot be read: {error}")
            return
        self._schedule_check(free)
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
                self._pending.append(Event("disk", text))
        else:
            self._warned = False

    def _schedule_check(self, free: int) -> None:
        """The next check within DISK_CHECK_INTERVAL_S of the rows' clock, sooner if the free space falls so
        fast that it would lose 1/FREE_SPACE_SHARE of the room above the minimum before."""
        now = self._last_row_s
        interval = DISK_CHECK_INTERVAL_S
        if now is not None and self._last_free is not None and now > self._last_free[0]:
            falling_bytes_per_s = (self._last_free[1] - free) / (now - self._last_free[0])
            if falling_bytes_per_s > 0:
                room = max(free - self.min_free_bytes, 0)
                interval = min(interval, room / falling_bytes_per_s / FREE_SPACE_SHARE)
        if now is not None:
            self._last_free = (now, free)
            self._next_check_s = now + interval
        else:
            self._next_check_s = -float("inf")          # at the first row

    def _fail(self, reason: str) -> None:
        if self.failure is not None:
            return
        self.failure = reason
        log.critical("data log: %s", reason)
        self._pending.append(Event("disk", f"{reason}: stopping"))
        if self.on_failure is not None:
            self.on_failure(reason)

    def _describe_target(self) -> str:
        return str(self._file.path) if self._file is not None else str(self.directory)

    def _sync_if_due(self, force: bool = False) -> None:
        record_file = self._file
        if record_file is None or not self._dirty:
            return
        if force or time.monotonic() - self._last_fsync >= self.fsync_interval_s:
            self._sync(record_file)

    def _sync(self, record_file: RecordFile) -> None:
        record_file.sync()
        self._last_fsync = time.monotonic()
        self._dirty = False
