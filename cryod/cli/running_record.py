"""The record a running daemon is writing, for tools given no path (``cryod plot``).

Examples
--------
>>> running_record_path(Path("/nonexistent/cryod.sock"))
Traceback (most recent call last):
...
ConnectionError: no cryod daemon listening at /nonexistent/cryod.sock (No such file or directory); give the record's path
"""

from __future__ import annotations

from pathlib import Path


def running_record_path(socket: Path | None = None) -> Path:
    """The path of the record the daemon at ``socket`` (default: found as ``cryod ctl`` finds it) is writing.

    Raises
    ------
    ConnectionError
        No daemon answers, or it has no record yet; the message says which.
    """
    from cryod.client import DaemonClient

    try:
        client = DaemonClient(socket)
        path = client.record_path()
    except ConnectionError as error:
        raise ConnectionError(f"{error}; give the record's path") from None
    if path is None:
        raise ConnectionError(f"the daemon at {client.socket} has no record yet; try again once it runs, "
                              f"or give a record's path")
    return Path(path)
