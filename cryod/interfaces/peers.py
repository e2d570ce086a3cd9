"""Who is at the other end of a TCP connection, from the kernel's socket table, and whether that user may command.

A connection from this computer (loopback) has two ends in ``/proc/net/tcp`` (or ``tcp6``): the
server's and the client's, whose line carries the uid of the process that opened it and the bytes
it has received and not yet read (``rx_queue``). :func:`loopback_peer` finds the client's line, so
the interfaces can say which user sent a command and refuse writes from users that the control
socket would refuse (:func:`may_use_socket`: the socket file's owner, group and mode, as the
kernel judges a ``connect``), and can tell an event stream whose client reads nothing from one that
keeps up.

Examples
--------
>>> _address("0100007F:1F90")
('127.0.0.1', 8080)
>>> _address("00000000000000000000000001000000:1F90")
('::1', 8080)
"""

from __future__ import annotations

import grp
import ipaddress
import os
import pwd
import socket
import stat
import struct
from dataclasses import dataclass
from pathlib import Path

#: The kernel's tables of TCP sockets.
TABLES = (Path("/proc/net/tcp"), Path("/proc/net/tcp6"))


@dataclass(frozen=True)
class PeerSocket:
    """The client's end of a loopback connection, as the kernel lists it."""

    uid: int
    unread_bytes: int


def _address(text: str) -> tuple[str, int]:
    """``/proc/net/tcp``'s ``HEXADDR:HEXPORT`` (each 32-bit word in the host's byte order) as (address, port)."""
    host, port = text.split(":")
    raw = bytes.fromhex(host)
    words = b"".join(struct.pack("@I", struct.unpack(">I", raw[index:index + 4])[0]) for index in range(0, len(raw), 4))
    address = ipaddress.ip_address(words)
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped
    return str(address), int(port, 16)


def _normal(host: str) -> str:
    address = ipaddress.ip_address(host.split("%")[0])
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped
    return str(address)


def loopback_peer(client: tuple[str, int], server: tuple[str, int]) -> PeerSocket | None:
    """The client's end of the connection from ``client`` to ``server`` (address, port), None when the kernel lists
    no such socket on this computer (a client elsewhere)."""
    wanted = ((_normal(client[0]), int(client[1])), (_normal(server[0]), int(server[1])))
    for table in TABLES:
        try:
            lines = table.read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            if len(fields) < 8:
                continue
            try:
                if (_address(fields[1]), _address(fields[2])) != wanted:
                    continue
                _, unread = fields[4].split(":")
                return PeerSocket(uid=int(fields[7]), unread_bytes=int(unread, 16))
            except ValueError:
                continue
    return None


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address) is this computer's loopback."""
    try:
        return ipaddress.ip_address(_normal(host)).is_loopback
    except ValueError:
        return False


def user_name(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return "no user name"


def may_use_socket(uid: int, socket_path: Path) -> bool:
    """Whether the user ``uid`` may connect to the Unix socket at ``socket_path`` (write permission on it, as the
    kernel checks: owner, then group (primary or supplementary), then others; root always)."""
    if uid == 0:
        return True
    try:
        info = os.stat(socket_path)
    except OSError:
        return False
    mode = stat.S_IMODE(info.st_mode)
    if uid == info.st_uid:
        return bool(mode & stat.S_IWUSR)
    try:
        user = pwd.getpwuid(uid)
        groups = {user.pw_gid} | {group.gr_gid for group in grp.getgrall() if user.pw_name in group.gr_mem}
    except KeyError:
        groups = set()
    if info.st_gid in groups:
        return bool(mode & stat.S_IWGRP)
    return bool(mode & stat.S_IWOTH)


def unsent_bytes(connection: socket.socket) -> int:
    """Bytes this end has handed the kernel and the peer has not acknowledged yet (``SIOCOUTQ``); 0 when unknown."""
    import fcntl
    import termios

    try:
        return struct.unpack("i", fcntl.ioctl(connection.fileno(), termios.TIOCOUTQ, b"\0\0\0\0"))[0]
    except (OSError, ValueError):
        return 0


__all__ = ["PeerSocket", "loopback_peer", "is_loopback", "may_use_socket", "unsent_bytes", "user_name"]
