"""Who is at the other end of a TCP connection, from the kernel's socket table, and whether that user may command.

A connection from this computer (loopback) has two ends in the kernel's table of sockets: the
server's and the client's, which records the uid of the process that opened it and the bytes it
has received and not yet read. :func:`loopback_peer` asks the kernel for the client's end by its
four addresses (netlink ``sock_diag``, the interface ``ss`` uses: one exact lookup, however many
sockets the computer has), so that the interfaces can say which user sent a command and refuse
writes from users that the control socket would refuse (:func:`may_use_socket`: the socket file's
owner, group and mode, as the kernel judges a ``connect``), and can tell an event stream whose
client reads nothing from one that keeps up.

Examples
--------
>>> import socket
>>> server = socket.create_server(("127.0.0.1", 0))
>>> client = socket.create_connection(server.getsockname())
>>> peer = loopback_peer(client.getsockname(), server.getsockname())
>>> peer.uid == os.geteuid(), peer.unread_bytes
(True, 0)
>>> client.close(); server.close()
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

#: netlink's socket diagnostics (linux/sock_diag.h, linux/inet_diag.h).
NETLINK_SOCK_DIAG, SOCK_DIAG_BY_FAMILY, NLM_F_REQUEST, NLMSG_ERROR = 4, 20, 1, 2
#: Every TCP state, and "no cookie" (the socket is found by its addresses).
_ALL_STATES, _NO_COOKIE = 0xFFFFFFFF, 0xFFFFFFFF
_HEADER = struct.Struct("=IHHII")                   # nlmsghdr: length, type, flags, sequence, port id
_REQUEST = struct.Struct("=BBBBI")                  # inet_diag_req_v2: family, protocol, extensions, pad, states
_SOCKET_ID = struct.Struct(">HH16s16s")             # inet_diag_sockid: ports, addresses (network order)
_SOCKET_ID_REST = struct.Struct("=III")             # its interface and cookie (host order)
_MESSAGE = struct.Struct("=BBBB")                   # inet_diag_msg: family, state, timer, retransmits
_MESSAGE_REST = struct.Struct("=IIIII")             # expires, receive queue, send queue, uid, inode


@dataclass(frozen=True)
class PeerSocket:
    """The client's end of a loopback connection, as the kernel lists it."""

    uid: int
    unread_bytes: int


def _packed(host: str) -> tuple[int, bytes]:
    """(address family, 16 bytes of the address as inet_diag takes it)."""
    address = ipaddress.ip_address(host.split("%")[0])
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped
    if isinstance(address, ipaddress.IPv4Address):
        return socket.AF_INET, address.packed + bytes(12)
    return socket.AF_INET6, address.packed


def loopback_peer(client: tuple[str, int], server: tuple[str, int]) -> PeerSocket | None:
    """The client's end of the connection from ``client`` to ``server`` (address, port), None when the kernel lists
    no such socket on this computer (a client elsewhere) or cannot be asked."""
    try:
        family, source = _packed(client[0])
        _, destination = _packed(server[0])
    except ValueError:
        return None
    request = (_REQUEST.pack(family, socket.IPPROTO_TCP, 0, 0, _ALL_STATES)
               + _SOCKET_ID.pack(int(client[1]), int(server[1]), source, destination)
               + _SOCKET_ID_REST.pack(0, _NO_COOKIE, _NO_COOKIE))
    message = _HEADER.pack(_HEADER.size + len(request), SOCK_DIAG_BY_FAMILY, NLM_F_REQUEST, 1, 0) + request
    try:
        with socket.socket(socket.AF_NETLINK, socket.SOCK_DGRAM, NETLINK_SOCK_DIAG) as netlink:
            netlink.settimeout(1.0)
            netlink.send(message)
            reply = netlink.recv(65536)
    except OSError:
        return None
    if len(reply) < _HEADER.size:
        return None
    _, kind, _, _, _ = _HEADER.unpack_from(reply)
    body = _HEADER.size + _MESSAGE.size + _SOCKET_ID.size + _SOCKET_ID_REST.size
    if kind != SOCK_DIAG_BY_FAMILY or len(reply) < body + _MESSAGE_REST.size:
        return None                                 # NLMSG_ERROR: no such socket
    _, unread, _, uid, _ = _MESSAGE_REST.unpack_from(reply, body)
    return PeerSocket(uid=uid, unread_bytes=unread)


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address) is this computer's loopback."""
    try:
        address = ipaddress.ip_address(host.split("%")[0])
    except ValueError:
        return False
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped
    return address.is_loopback


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
