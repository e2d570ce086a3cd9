"""Host-wide exclusive locks taken before any instrument is touched: one daemon per cryostat, one per instrument.

Opening the instruments resets them (``*CLS``, heater output off, 0 A), so a second daemon
started on the same hardware would switch off the first one's heater and then drive it under
its own limits. Two locks keep it out, both ``flock`` on a file, which the kernel releases when
the process ends, however it ends, so a crash leaves no stale lock behind:

- :class:`InstanceLock`: beside the control socket (``<socket>.lock``): a second daemon of the
  same configuration.
- :class:`InstrumentLocks`: one file per instrument address, in ``instruments.lock_directory``
  (``/run/lock/cryod``, shared by every cryod on the host), named from the address's one
  spelling (:mod:`drivers.transports.addresses`): a second daemon of another configuration
  naming the same supply, DMM, Prologix controller or trigger port.

A lock file holds who holds it (process id, configuration file, the key naming the
instrument), for the refusal of the next one; it is only ever locked, never trusted by its
content, and never removed (a file removed while locked would let a third daemon lock a new one).

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
>>> supply = {"TCPIP0::10.0.0.5::1234::SOCKET": ["instruments.heater_supply"]}
>>> one = InstrumentLocks(folder, supply, "/etc/cryod/a.yaml")
>>> one.acquire()
>>> try:
...     InstrumentLocks(folder, supply, "/etc/cryod/b.yaml").acquire()
... except InstrumentInUse as error:
...     print("refused:", "/etc/cryod/a.yaml" in str(error))
refused: True
>>> one.release()
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import os
import re
from pathlib import Path


class AlreadyRunning(RuntimeError):
    """Another daemon holds the lock of this cryostat; ``holder`` names its process (``process 4242``)."""

    holder = "process unknown"


class InstrumentInUse(AlreadyRunning):
    """Another daemon holds the lock of a configured instrument."""


def _exclusive(path: Path, mode: int = 0o644) -> tuple[int, bool]:
    """An open descriptor of ``path`` and whether this process now holds its lock.

    Opened for writing where permitted (to say who holds it), for reading otherwise (``flock``
    needs no more): daemons of several users share one lock directory."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, mode)
    except PermissionError:
        fd = os.open(path, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return fd, False
    return fd, True


def _say_holder(fd: int, text: str) -> None:
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, (text + "\n").encode("utf-8"), 0)
    except OSError as error:            # opened read-only: the lock holds all the same
        if error.errno not in (errno.EBADF, errno.EINVAL, errno.EACCES, errno.EPERM):
            raise


def _holder(fd: int) -> str:
    try:
        return os.pread(fd, 512, 0).decode("utf-8", "replace").strip() or "process unknown"
    except OSError:
        return "process unknown"


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
        fd, held = _exclusive(self.path)
        if not held:
            holder = _holder(fd).removeprefix("process ")
            os.close(fd)
            error = AlreadyRunning(f"another cryod daemon (process {holder}) holds {self.path}: it runs this "
                                   f"cryostat; no instrument was touched")
            error.holder = f"process {holder}"
            raise error
        _say_holder(fd, f"{os.getpid()}")
        self._fd = fd

    def release(self) -> None:
        """Give the lock up (the file stays; it is only ever locked, never trusted by its content)."""
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None


def lock_file_name(address: str) -> str:
    """The lock file's name for a canonical instrument address: readable, and distinct per address."""
    readable = re.sub(r"[^A-Za-z0-9.-]+", "_", address).strip("_")[:100]
    return f"{readable}.{hashlib.sha256(address.encode('utf-8')).hexdigest()[:12]}.lock"


class InstrumentLocks:
    """The locks of the instruments one daemon drives, taken all or none.

    Parameters
    ----------
    directory : pathlib.Path
        ``instruments.lock_directory``, shared by every cryod on the host.
    addresses : dict
        Canonical address -> the configuration keys naming it (:func:`cryod.service.instruments.
        instrument_addresses`).
    configuration : str
        This daemon's configuration file, for the refusal another daemon gets.
    """

    def __init__(self, directory: Path, addresses: dict[str, list[str]], configuration: str):
        self.directory = Path(directory)
        self.addresses = dict(addresses)
        self.configuration = configuration or "an unnamed configuration"
        self._held: list[int] = []

    def acquire(self) -> None:
        """Lock every address, or none; :class:`InstrumentInUse` names each instrument another daemon holds,
        its key and that daemon. OSError when the directory cannot be made or written."""
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise OSError(f"instruments.lock_directory {self.directory} cannot be created: "
                          f"{error.strerror or error}") from None
        taken = []
        try:
            for address in sorted(self.addresses):
                keys = " and ".join(self.addresses[address])
                try:
                    fd, held = _exclusive(self.directory / lock_file_name(address), 0o660)
                except OSError as error:
                    raise OSError(f"instruments.lock_directory {self.directory}: cannot lock {address} "
                                  f"({keys}): {error.strerror or error}") from None
                if not held:
                    taken.append(f"{keys} {address} is driven by another cryod ({_holder(fd)})")
                    os.close(fd)
                    continue
                _say_holder(fd, f"process {os.getpid()} with {self.configuration}, as {keys}")
                self._held.append(fd)
            if taken:
                raise InstrumentInUse(f"{'; '.join(taken)}; not started, no instrument was touched: give each "
                                      f"daemon its own instruments")
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        """Give every lock up (the files stay)."""
        while self._held:
            fd = self._held.pop()
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)


__all__ = ["AlreadyRunning", "InstanceLock", "InstrumentInUse", "InstrumentLocks", "lock_file_name"]
