"""One record file as the data log writes it: created new, written whole lines at a time, disk space held
ahead of its end, and watched for what others do to it.

* **Created new**: ``O_EXCL``, so an existing file is never written.
* **Whole lines**: a write that fails (a full disk, a file size limit, an I/O
  error) is cut back to where it began, so the file never ends inside a line
  written after the failure and every line before it stays as it was.
* **Room held ahead**: :meth:`RecordFile.reserve` allocates the disk blocks of
  the next :data:`RESERVE_BYTES` beyond the file's end without changing its
  length (``fallocate`` with ``FALLOC_FL_KEEP_SIZE``: ext4, XFS, Btrfs, tmpfs).
  Lines written there cannot fail for want of space, so when another program
  fills the disk, the last rows and the stop event still go in; the space held
  is given back when the file closes. On a file system without the call
  (:attr:`RecordFile.holds_room` false) only the free-space checks protect the
  record.
* **Watched**: :meth:`RecordFile.check` finds the file deleted, renamed or
  replaced at its path, or written by someone else.

Examples
--------
>>> import tempfile
>>> folder = Path(tempfile.mkdtemp())
>>> record = RecordFile(folder / "cryod-2026-11-25.csv")
>>> record.write(b"# cryod-log v1\\n")
>>> record.check(at_path=True) is None
True
>>> (folder / "cryod-2026-11-25.csv").unlink()
>>> record.check(at_path=True)
'deleted'
>>> record.close(); folder.rmdir()
"""

from __future__ import annotations

import ctypes
import errno
import os
from pathlib import Path

#: Disk space held beyond the end of the file being written (about 4000 rows, 5 minutes at 80 ms).
RESERVE_BYTES = 1 << 20

_KEEP_SIZE = 0x01           # FALLOC_FL_KEEP_SIZE: allocate without changing the file's length
_PUNCH_HOLE = 0x02          # FALLOC_FL_PUNCH_HOLE: give the blocks back (with KEEP_SIZE)
#: errno values saying the file system cannot hold room this way (the record is written all the same).
_NOT_SUPPORTED = {errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL, errno.ENODEV}


def _fallocate_call():
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        call = getattr(libc, "fallocate64", None) or libc.fallocate
    except (OSError, AttributeError):
        return None
    call.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int64, ctypes.c_int64]
    call.restype = ctypes.c_int
    return call


_FALLOCATE = _fallocate_call()


def _fallocate(descriptor: int, mode: int, offset: int, length: int) -> None:
    """Linux ``fallocate(2)``; raises OSError (ENOTSUP where there is no such call)."""
    if _FALLOCATE is None:
        raise OSError(errno.ENOTSUP, "fallocate is not available")
    if _FALLOCATE(descriptor, mode, offset, length) != 0:
        number = ctypes.get_errno()
        raise OSError(number, os.strerror(number))


class RecordFile:
    """A new file, written at its end by this object only.

    Parameters
    ----------
    path : pathlib.Path
        Must not exist (``FileExistsError`` otherwise).

    Attributes
    ----------
    path : pathlib.Path
    size : int
        Bytes written (where the next write goes).
    holds_room : bool
        Disk space can be held ahead of the end on this file system.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self._descriptor = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
        status = os.fstat(self._descriptor)
        self._identity = (status.st_dev, status.st_ino)
        self.size = 0
        self._held_to = 0
        self.holds_room = _FALLOCATE is not None

    def write(self, data: bytes) -> None:
        """Write ``data`` at the end, all of it or nothing.

        Raises
        ------
        OSError
            The write failed; the file is cut back to its length before it (when the file system lets it).
        """
        start = self.size
        view = memoryview(data)
        try:
            while view:
                written = os.write(self._descriptor, view)
                view = view[written:]
                self.size += written
        except OSError:
            try:
                os.ftruncate(self._descriptor, start)
                os.lseek(self._descriptor, start, os.SEEK_SET)
                self.size = start
            except OSError:
                pass
            raise

    @property
    def room_held(self) -> int | None:
        """Bytes that can still be written into the space held (None: no space held on this file system)."""
        return max(self._held_to - self.size, 0) if self.holds_room else None

    def reserve(self, length: int = RESERVE_BYTES) -> None:
        """Hold the disk space of the next ``length`` bytes beyond the end (the file's length is unchanged).

        Raises
        ------
        OSError
            ENOSPC: the disk has not that much room (what was held before is still held). A file system
            that cannot hold room sets :attr:`holds_room` false instead.
        """
        if not self.holds_room:
            return
        try:
            _fallocate(self._descriptor, _KEEP_SIZE, self.size, length)
        except OSError as error:
            if error.errno in _NOT_SUPPORTED:
                self.holds_room = False
                return
            raise
        self._held_to = self.size + length

    def check(self, at_path: bool) -> str | None:
        """What others did to the file, or None.

        Parameters
        ----------
        at_path : bool
            Also look at the path (renamed, replaced): a lookup by name, done less often than the look at
            the open file (deleted, written by someone else).

        Returns
        -------
        str or None
            ``"deleted"``, ``"changed by another writer (N bytes where M were written)"``,
            ``"moved away from its path"``, ``"replaced by another file at its path"``.
        """
        status = os.fstat(self._descriptor)
        if status.st_nlink == 0:
            return "deleted"
        if status.st_size != self.size:
            return f"changed by another writer ({status.st_size} bytes where {self.size} were written)"
        if at_path:
            try:
                here = os.stat(self.path)
            except FileNotFoundError:           # deleted between the two looks, or renamed: the open file tells
                return "deleted" if os.fstat(self._descriptor).st_nlink == 0 else "moved away from its path"
            if (here.st_dev, here.st_ino) != self._identity:
                return "replaced by another file at its path"
        return None

    @property
    def still_ours(self) -> bool:
        """The file is still linked somewhere and holds only what was written (an event may go into it)."""
        status = os.fstat(self._descriptor)
        return status.st_nlink > 0 and status.st_size == self.size

    def sync(self) -> None:
        os.fsync(self._descriptor)

    def close(self) -> None:
        """Give back the space held, sync and close (the descriptor is closed whatever fails)."""
        if self._descriptor < 0:
            return
        try:
            if self._held_to > self.size and os.fstat(self._descriptor).st_size == self.size:   # only ours
                for give_back in (lambda: _fallocate(self._descriptor, _KEEP_SIZE | _PUNCH_HOLE, self.size,
                                                     self._held_to - self.size),       # tmpfs
                                  lambda: os.ftruncate(self._descriptor, self.size)):  # ext4, XFS
                    try:
                        give_back()
                    except OSError:
                        pass
            os.fsync(self._descriptor)
        finally:
            os.close(self._descriptor)
            self._descriptor = -1


__all__ = ["RESERVE_BYTES", "RecordFile"]
