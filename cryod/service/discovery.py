"""Where ``cryod ctl`` and the Python client find a running daemon.

The service's socket is in its configuration (``control_socket.path``, by
default ``/run/cryod/control.sock`` from ``/etc/cryod/cryod.yaml``). A dry run
(``cryod --simulate``) listens by default on a per-user socket,
``$XDG_RUNTIME_DIR/cryod/simulate.sock`` (or ``/tmp/cryod-<uid>/simulate.sock``
where there is no runtime directory), so ``cryod ctl status`` beside it finds
it without options. The per-user directory is made private (0700) and is
refused if another user owns it or others may write into it.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

#: The service's configuration when none is given.
SERVICE_CONFIG = Path("/etc/cryod/cryod.yaml")
#: File name of a dry run's socket in the per-user directory.
SIMULATION_SOCKET_NAME = "simulate.sock"


class NoDaemonFound(ConnectionError):
    """No socket to talk to; the message says where it looked."""


def user_directory(create: bool = False) -> Path:
    """The per-user directory of a dry run's socket.

    Parameters
    ----------
    create : bool
        Make it (mode 0700) if missing.

    Raises
    ------
    PermissionError
        It exists but belongs to another user or others may write into it.
    """
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    base = Path(runtime) / "cryod" if runtime and Path(runtime).is_dir() else Path(f"/tmp/cryod-{os.getuid()}")
    if create:
        base.mkdir(mode=0o700, parents=True, exist_ok=True)
    if base.exists():
        info = base.lstat()
        if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid() or info.st_mode & 0o022:
            raise PermissionError(f"{base} is not a private directory of this user (owner uid {info.st_uid}, "
                                  f"mode {stat.S_IMODE(info.st_mode):o}); remove it or give --socket")
    return base


def simulation_socket(create_directory: bool = False) -> Path:
    """The default socket of ``cryod --simulate`` for this user."""
    return user_directory(create_directory) / SIMULATION_SOCKET_NAME


def find_daemon_socket() -> Path:
    """The socket of the daemon to talk to when none is named.

    The service's (from :data:`SERVICE_CONFIG`, when that file exists) if it is
    there, else this user's dry run's.

    Raises
    ------
    NoDaemonFound
        Neither socket exists; the message lists the places tried.
    cryod.yaml_source.FileFormatError
        The service's configuration exists but cannot be read.
    """
    tried = []
    if SERVICE_CONFIG.exists():
        from cryod.config import load_config

        path = load_config(SERVICE_CONFIG).control_socket.path
        if _is_socket(path):
            return path
        tried.append(f"{path} (control_socket.path of {SERVICE_CONFIG})")
    else:
        tried.append(f"{SERVICE_CONFIG} (absent: no service configured here)")
    try:
        path = simulation_socket()
    except PermissionError as error:
        tried.append(str(error))
    else:
        if _is_socket(path):
            return path
        tried.append(f"{path} (a cryod --simulate of this user)")
    raise NoDaemonFound("no running cryod found; looked at " + "; ".join(tried) +
                        ". Give --socket PATH (a dry run prints its socket at start) or --config PATH")


def _is_socket(path: Path) -> bool:
    try:
        return stat.S_ISSOCK(Path(path).stat().st_mode)
    except OSError:
        return False
