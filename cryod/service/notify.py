"""systemd's notify protocol: READY, STATUS, WATCHDOG, RELOADING, STOPPING.

A datagram to the socket named in ``$NOTIFY_SOCKET`` (a path, or ``@name`` for
the abstract namespace). Without ``$NOTIFY_SOCKET`` (not under systemd, or
Type=simple) every call does nothing.

Examples
--------
>>> notifier = SystemdNotifier(environ={})
>>> notifier.enabled
False
>>> notifier.ready("regulating")      # no socket: nothing sent
"""

from __future__ import annotations

import os
import socket
import threading
import time
from typing import Mapping

from cryod.instrument_waits import WATCHDOG_PING_SHARE


class SystemdNotifier:
    """Sends sd_notify messages; rate-limits watchdog pings.

    Parameters
    ----------
    environ : mapping, optional
        Environment to read ``NOTIFY_SOCKET`` and ``WATCHDOG_USEC`` from
        (default: ``os.environ``).
    """

    def __init__(self, environ: Mapping[str, str] | None = None):
        environ = os.environ if environ is None else environ
        address = environ.get("NOTIFY_SOCKET", "")
        self._address = ("\0" + address[1:]) if address.startswith("@") else address
        self.enabled = bool(address)
        self._socket: socket.socket | None = None
        self._lock = threading.Lock()
        watchdog_usec = environ.get("WATCHDOG_USEC", "")
        watchdog_pid = environ.get("WATCHDOG_PID", "")
        self.watchdog_interval_s: float | None = None
        if watchdog_usec.isdigit() and int(watchdog_usec) > 0 and (not watchdog_pid or watchdog_pid == str(os.getpid())):
            self.watchdog_interval_s = int(watchdog_usec) / 1e6
        self._last_ping = -float("inf")
        self.dropped = 0

    def send(self, *fields: str) -> None:
        """Send ``KEY=value`` fields as one datagram.

        Never blocks (the loop thread sends the watchdog pings): a full or
        missing receiver drops the message, and errors are ignored, since the
        service must go on.
        """
        if not self.enabled:
            return
        message = "\n".join(fields).encode("utf-8")
        with self._lock:
            try:
                if self._socket is None:
                    self._socket = socket.socket(socket.AF_UNIX,
                                                 socket.SOCK_DGRAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK)
                self._socket.sendto(message, self._address)
            except OSError:
                self.dropped += 1

    def ready(self, status: str) -> None:
        self.send("READY=1", f"STATUS={status}")

    def status(self, status: str) -> None:
        self.send(f"STATUS={status}")

    def reloading(self) -> None:
        self.send("RELOADING=1", f"MONOTONIC_USEC={time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000}")

    def reloaded(self, status: str) -> None:
        self.send("READY=1", f"STATUS={status}")

    def stopping(self, status: str) -> None:
        self.send("STOPPING=1", f"STATUS={status}")

    def watchdog(self) -> None:
        """WATCHDOG=1, at most once per :data:`~cryod.instrument_waits.WATCHDOG_PING_SHARE` of the watchdog
        interval (cheap to call every tick)."""
        if self.watchdog_interval_s is None:
            return
        now = time.monotonic()
        if now - self._last_ping >= self.watchdog_interval_s * WATCHDOG_PING_SHARE:
            self._last_ping = now
            self.send("WATCHDOG=1")

    def close(self) -> None:
        with self._lock:
            if self._socket is not None:
                self._socket.close()
                self._socket = None
