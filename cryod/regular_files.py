"""Reading a file that must be a regular file: configurations, models, calibration curves.

A path can name something that is not a file: a named pipe (FIFO), whose opening
waits for a writer that may never come; a device such as ``/dev/zero``, which never
ends; a socket; a directory. :func:`regular_file_bytes` refuses each of them by
name before reading, and opens without waiting, so that even a file replaced by a
pipe between the look and the opening cannot stall the reader (a reload on the
daemon's service thread, ``cryod run --check``).

Examples
--------
>>> import os, tempfile
>>> folder = tempfile.mkdtemp()
>>> pipe = os.path.join(folder, "cryod.yaml")
>>> os.mkfifo(pipe)
>>> regular_file_bytes(pipe, 100)
Traceback (most recent call last):
...
cryod.regular_files.NotARegularFile: a named pipe (FIFO), not a regular file
>>> regular_file_bytes("/dev/zero", 100)
Traceback (most recent call last):
...
cryod.regular_files.NotARegularFile: a character device, not a regular file
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

#: What a path names when it is not a regular file, in words.
_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


class NotARegularFile(OSError):
    """The path names a directory, a named pipe, a device or a socket, not a file."""


def kind_of(mode: int) -> str | None:
    """What ``mode`` (``st_mode``) is when it is not a regular file, in words; None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    return next((words for test, words in _KINDS if test(mode)), "not a regular file")


def regular_file_bytes(path: str | Path, max_bytes: int) -> bytes:
    """Up to ``max_bytes + 1`` bytes of the regular file at ``path`` (one more tells a file that is too long).

    Parameters
    ----------
    path : str or pathlib.Path
    max_bytes : int

    Returns
    -------
    bytes

    Raises
    ------
    NotARegularFile
        ``path`` names a directory, a named pipe, a device or a socket (checked before opening,
        and again on what was opened).
    OSError
        The file is missing or cannot be read (FileNotFoundError, PermissionError, ...).
    """
    kind = kind_of(os.stat(path).st_mode)
    if kind is not None:
        raise NotARegularFile(f"{kind}, not a regular file")
    # O_NONBLOCK: a pipe put in the file's place meanwhile opens at once instead of waiting for a writer
    descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    with os.fdopen(descriptor, "rb") as stream:
        kind = kind_of(os.fstat(descriptor).st_mode)
        if kind is not None:
            raise NotARegularFile(f"{kind}, not a regular file")
        return stream.read(max_bytes + 1)


__all__ = ["NotARegularFile", "kind_of", "regular_file_bytes"]
