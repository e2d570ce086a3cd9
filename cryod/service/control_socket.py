"""The local control socket: ``cryod ctl`` talks to the running daemon through it.

A Unix stream socket; one command line in, one JSON line out::

    status                  -> {"ok": true, "message": "status", "status": {...}}
    setpoint 5.0            -> {"ok": true, "message": "setpoint 5 K", "status": {...}}

The commands are the table in :mod:`cryod.service.commands`. A malformed command is refused here with the reason; the values are checked
against the configured limits by the loop itself, which refuses anything
outside them. Commands reach the loop through its queue and take effect at
the next tick boundary.
"""

from __future__ import annotations

import grp
import json
import logging
import math
import os
import pwd
import socket
import socketserver
import stat
import threading
from pathlib import Path
from typing import Callable

from cryod.service.commands import Command, parse_command, wait_for

log = logging.getLogger("cryod.control")

MAX_LINE = 256


class ControlSocketServer:
    """Serves the control socket from its own thread.

    Parameters
    ----------
    path : pathlib.Path
        Socket file.
    mode : int
        File mode of the socket (e.g. 0o660).
    owner, group : str, optional
        Owner and group to give the socket (needs the privilege to chown).
    submit : callable
        Hands a command to the loop (``ControlLoop.submit``).
    status : callable
        Returns the loop's current status as a dict.
    reply_timeout_s : float
        How long to wait for the loop's answer.
    """

    def __init__(self, path: Path, mode: int, owner: str | None, group: str | None,
                 submit: Callable[[Command], Command], status: Callable[[], dict], reply_timeout_s: float = 5.0):
        self.path = Path(path)
        self.mode = mode
        self.owner = owner
        self.group = group
        self.submit = submit
        self.status = status
        self.reply_timeout_s = reply_timeout_s
        self._server: socketserver.UnixStreamServer | None = None
        self._thread: threading.Thread | None = None

    def handle_line(self, line: str) -> dict:
        """The reply to one command line (also used by tests without a socket)."""
        try:
            command = parse_command(line)
        except ValueError as error:
            return {"ok": False, "message": str(error)}
        if command.name == "status":
            return {"ok": True, "message": "status", "status": self.status()}
        answered = wait_for(self.submit(command), self.reply_timeout_s)
        return {"ok": answered.ok, "message": answered.message, "status": self.status()}

    def start(self) -> None:
        """Bind (replacing a stale socket file, never another kind of file) and serve."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists() or self.path.is_symlink():
            if not stat.S_ISSOCK(self.path.lstat().st_mode):
                raise OSError(f"control socket path {self.path} exists and is not a socket; not replacing it")
            if _socket_answers(self.path):
                raise OSError(f"control socket {self.path} is in use by another running daemon")
            self.path.unlink()
        owner = self

        class Handler(socketserver.StreamRequestHandler):
            def handle(self):
                self.connection.settimeout(owner.reply_timeout_s + 5.0)
                try:
                    raw = self.rfile.readline(MAX_LINE + 1)
                except OSError:
                    return
                if len(raw) > MAX_LINE:
                    reply = {"ok": False, "message": f"command longer than {MAX_LINE} bytes refused"}
                else:
                    try:
                        line = raw.decode("utf-8")
                    except UnicodeDecodeError:
                        reply = {"ok": False, "message": "command is not UTF-8 text"}
                    else:
                        reply = owner.handle_line(line)
                try:
                    self.wfile.write((json.dumps(finite_or_none(reply)) + "\n").encode("utf-8"))
                except OSError:
                    pass

        old_umask = os.umask(0o177)
        try:
            self._server = socketserver.ThreadingUnixStreamServer(str(self.path), Handler)
        finally:
            os.umask(old_umask)
        self._server.daemon_threads = True
        os.chmod(self.path, self.mode)
        if self.owner or self.group:
            uid = pwd.getpwnam(self.owner).pw_uid if self.owner else -1
            gid = grp.getgrnam(self.group).gr_gid if self.group else -1
            os.chown(self.path, uid, gid)
        # polled every 0.1 s for the stop: stopping the daemon waits at most that long for the socket
        self._thread = threading.Thread(target=self._server.serve_forever, args=(0.1,), name="cryod-control",
                                        daemon=True)
        self._thread.start()
        log.info("control socket: %s (mode %o)", self.path, self.mode)

    def stop(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
            try:
                self.path.unlink()
            except FileNotFoundError:
                pass


def finite_or_none(value):
    """JSON-safe copy: NaN and infinities become null (strict JSON has no NaN)."""
    if isinstance(value, dict):
        return {key: finite_or_none(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _socket_answers(path: Path) -> bool:
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(0.5)
    try:
        probe.connect(str(path))
        return True
    except OSError:
        return False
    finally:
        probe.close()


def send_command(path: Path, line: str, timeout_s: float = 10.0) -> dict:
    """Client side: send one command line, return the decoded reply.

    Raises
    ------
    ConnectionError
        When no daemon listens at ``path``.
    """
    client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    client.settimeout(timeout_s)
    try:
        client.connect(str(path))
    except (FileNotFoundError, ConnectionRefusedError) as error:
        raise ConnectionError(f"no cryod daemon listening at {path} ({error.strerror})") from None
    except PermissionError:
        raise ConnectionError(f"not allowed to use {path}: check control_socket.group/mode and your groups") from None
    try:
        client.sendall((line.strip() + "\n").encode("utf-8"))
        stream = client.makefile("rb")
        raw = stream.readline()
    finally:
        client.close()
    if not raw:
        raise ConnectionError(f"the daemon at {path} closed the connection without a reply")
    return json.loads(raw.decode("utf-8"))
