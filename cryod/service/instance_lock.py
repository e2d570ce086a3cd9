"""One daemon per cryostat: an exclusive lock taken before any instrument is touched.

Opening the instruments resets them (``*CLS``, heater output off, 0 A), so a
second daemon started on the same hardware would switch off the first one's
heater. The lock is ``flock`` on a file beside the control socket
(``<socket>.lock``), which two daemons of one cryostat share; the kernel
releases it when the process ends, however it ends, so a crash leaves no
stale lock behind.

Examples
--------
>>> import tempfile, pathlib
>>> folder = pathlib.Path(tempfile.mkdtemp())
>>> first = InstanceLock(folder / "control.sock")
>>> first.acquire()
>>> try:
...     InstanceLock(folder / "control.sock").acquire()
... except AlreadyRunning as error:
...     print("refused:", "another cryod daemon" in str(error))
refused: True
>>> first.release()
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path


class AlreadyRunning(RuntimeError):
    """Another daemon holds the lock of this cryostat."""


class InstanceLock:
    """The lock of the daemon using ``socket_path``.

    Parameters
    ----------
    socket_path : pathlib.Path
        The control socket; the lock file is beside it.
    """

    def __init__(self, socket_path: Path):
        self.path = Path(f"{socket_path}.lock")
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock, or raise :class:`AlreadyRunning` naming the holder's process id."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode("ascii", "replace").strip() or "unknown"
            os.close(fd)
            raise AlreadyRunning(f"another cryod daemon (process {holder}) holds {self.path}: it runs this "
                                 f"cryostat; no instrument was touched") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode("ascii"))
        self._fd = fd

    def release(self) -> None:
        """Give the lock up (the file stays; it is only ever locked, never trusted by its content)."""
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None
