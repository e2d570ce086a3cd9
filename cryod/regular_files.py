"""Only regular files are read where a file is expected.

A FIFO given as a record makes a reader wait for a writer that never comes, a
character device such as ``/dev/zero`` never ends, and opening some devices
has effects of its own. So the path is looked at with ``stat`` before it is
opened, anything but a regular file is refused with what it is, and the file is
then opened without waiting (``O_NONBLOCK``) and checked again on the open
descriptor, so that a FIFO put in its place meanwhile is refused as well.

Examples
--------
>>> try:
...     open_regular_file("/dev/null")
... except NotARegularFile as error:
...     print(error)
/dev/null: is a character device (like /dev/zero or a terminal), not a regular file
"""

from __future__ import annotations

import fcntl
import io
import os
import stat
from pathlib import Path

#: What each kind of file is called in messages.
_KINDS = (
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device (like /dev/zero or a terminal)"),
    (stat.S_ISBLK, "a block device (a whole disk or partition)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISDIR, "a directory"),
)


class NotARegularFile(ValueError):
    """A path that names something other than a regular file.

    Attributes
    ----------
    path : str
    reason : str
        What it is instead (``is a directory, not a regular file``).
    """

    def __init__(self, path: str | os.PathLike, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


def kind_of(mode: int) -> str:
    """What a file of ``mode`` (``st_mode``) is, in words: ``a FIFO (named pipe)``, ``a regular file``, ..."""
    if stat.S_ISREG(mode):
        return "a regular file"
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def _refuse_unless_regular(path, status: os.stat_result) -> None:
    if not stat.S_ISREG(status.st_mode):
        raise NotARegularFile(path, f"is {kind_of(status.st_mode)}, not a regular file")


def regular_file_status(path: str | os.PathLike) -> os.stat_result:
    """``os.stat(path)`` of a regular file (symbolic links followed).

    Raises
    ------
    NotARegularFile
        A FIFO, device, socket or directory.
    OSError
        No such file, or it cannot be looked at.
    """
    status = os.stat(path)
    _refuse_unless_regular(path, status)
    return status


def open_regular_file(path: str | os.PathLike) -> io.BufferedReader:
    """Open a regular file for reading in binary mode, refusing anything else before and after opening.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    io.BufferedReader

    Raises
    ------
    NotARegularFile
        A FIFO, device, socket or directory (also one put at the path while it was being opened).
    OSError
        No such file, no permission, ...
    """
    path = Path(path)
    before = regular_file_status(path)
    descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    try:
        opened = os.fstat(descriptor)
        _refuse_unless_regular(path, opened)
        if (opened.st_dev, opened.st_ino) != (before.st_dev, before.st_ino):
            raise NotARegularFile(path, "was replaced while it was being opened")
        flags = fcntl.fcntl(descriptor, fcntl.F_GETFL)
        fcntl.fcntl(descriptor, fcntl.F_SETFL, flags & ~os.O_NONBLOCK)
        return os.fdopen(descriptor, "rb")
    except BaseException:
        os.close(descriptor)
        raise


__all__ = ["NotARegularFile", "kind_of", "open_regular_file", "regular_file_status"]
