"""The local control socket: ``cryod ctl`` talks to the running daemon through it.

A Unix stream socket; one command line in, one JSON line out, then the server closes::

    status                  -> {"ok": true, "message": "status", "status": {...}}
    setpoint 5.0            -> {"ok": true, "message": "setpoint 5 K", "status": {...}}
    setpoint 1_5            -> {"ok": false, "message": "'setpoint' argument K: '1_5' is not a number ..."}

The commands are the table in :mod:`cryod.service.commands`. A malformed command is refused here
with the reason; the values are checked against the configured limits by the loop itself, which
refuses anything outside them. Commands reach the loop through its queue and take effect at the
next tick boundary.

Every connection gets one reply line, whatever it sent: a line longer than :data:`MAX_LINE` bytes,
text that is not UTF-8, or no complete line within :data:`LINE_TIMEOUT_S` are refused with the
reason. All clients are served by one thread with an asyncio event loop, so however many connect,
the socket competes with the control loop's thread as one thread, not one per client; the kernel
holds up to :data:`BACKLOG` connections until the server takes them, and a client finding even
that full waits for its turn (:func:`send_command`).

``heater-off`` always gets through. Up to :data:`MAX_CLIENTS` connections are open at once; one
more closes the one that has waited longest without sending its line
(:class:`cryod.service.async_clients.ConnectionBook`), so idle clients, however many, keep no one
out. When every connection open is waiting for the loop's answer, the :data:`RESERVED_CONNECTIONS`
beyond them carry only ``heater-off`` (anything else is answered ``busy: ...``, which
:func:`send_command` retries) and have :data:`RESERVED_LINE_TIMEOUT_S` to send it; beyond those, a
connection is answered ``busy`` at once.
"""

from __future__ import annotations

import asyncio
import grp
import json
import logging
import os
import pwd
import socket
import stat
import struct
import time
from pathlib import Path
from typing import Callable

from cryod.service.async_clients import ClientsThread, ConnectionBook, loop_answer
from cryod.service.commands import Command, parse_command, wait_for
from cryod.service.stream import StreamHub, finite_or_none

log = logging.getLogger("cryod.control")

#: Longest command line, bytes (without its newline).
MAX_LINE = 256
#: Longest relayed command line (``relay {...}``: the command and who sent it), bytes.
MAX_RELAY_LINE = 1024
#: Longest name of a relayed command's sender, characters.
MAX_SENDER = 200
#: Connections the kernel holds until the server takes them (a full backlog makes a client wait).
BACKLOG = 256
#: Connections open at once that carry any command (each costs a file descriptor, and a command waiting
#: for the loop: at 8 a tick, 256 commands are answered within 2.6 s); one more closes the one that has
#: waited longest without sending its line.
MAX_CLIENTS = 256
#: Connections beyond :data:`MAX_CLIENTS`, when every one open waits for the loop's answer, that carry only
#: heater-off.
RESERVED_CONNECTIONS = 64
#: How long a client has to send its command line, s.
LINE_TIMEOUT_S = 5.0
#: How long a connection beyond :data:`MAX_CLIENTS` has to send its line (a client sends it as it connects), s.
RESERVED_LINE_TIMEOUT_S = 1.0
#: The one command a connection beyond :data:`MAX_CLIENTS` may carry.
RESERVED_FOR = "heater-off"


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
    max_clients : int, optional
        Connections open at once carrying any command (default :data:`MAX_CLIENTS`).
    line_timeout_s : float, optional
        How long a client has to send its line, s (default :data:`LINE_TIMEOUT_S`).
    reserved_connections : int, optional
        Connections beyond ``max_clients`` carrying only heater-off (default :data:`RESERVED_CONNECTIONS`).
    stream : StreamHub, optional
        The daemon's live stream, served to ``subscribe`` (:mod:`cryod.service.stream`).
    """

    def __init__(self, path: Path, mode: int, owner: str | None, group: str | None,
                 submit: Callable[[Command], Command], status: Callable[[], dict], reply_timeout_s: float = 5.0,
                 max_clients: int | None = None, line_timeout_s: float | None = None,
                 reserved_connections: int | None = None, stream: StreamHub | None = None):
        self.path = Path(path)
        self.mode = mode
        self.owner = owner
        self.group = group
        self.submit = submit
        self.status = status
        self.reply_timeout_s = reply_timeout_s
        self.max_clients = MAX_CLIENTS if max_clients is None else max_clients
        self.line_timeout_s = LINE_TIMEOUT_S if line_timeout_s is None else line_timeout_s
        reserved = RESERVED_CONNECTIONS if reserved_connections is None else reserved_connections
        #: The connections open now (:attr:`ConnectionBook.open`), the most at once, those closed for room.
        self.connections = ConnectionBook(self.max_clients, reserved)
        self.stream = stream
        self._clients = ClientsThread("control socket", self._open_server)

    async def _open_server(self, listener: socket.socket) -> asyncio.AbstractServer:
        server = await asyncio.start_unix_server(self._serve_client, sock=listener, limit=MAX_RELAY_LINE,
                                                 backlog=BACKLOG)
        if self.stream is not None:
            asyncio.ensure_future(self.stream.run())        # cancelled with the clients at the stop
        return server

    # -- replies ----------------------------------------------------------------------
    def handle_line(self, line: str) -> dict:
        """The reply to one command line, waiting here for the loop's answer (tests without a socket)."""
        try:
            command = parse_command(line)
        except ValueError as error:
            return {"ok": False, "message": str(error)}
        if command.name == "status":
            return {"ok": True, "message": "status", "status": self.status()}
        answered = wait_for(self.submit(command), self.reply_timeout_s)
        return reply_to(answered, self.status())

    async def _reply_to_line(self, text: str, sender: str = "") -> dict:
        try:
            command = parse_command(text)
        except ValueError as error:
            return {"ok": False, "message": str(error)}
        if command.name == "status":
            return {"ok": True, "message": "status", "status": self.status()}
        command.sender = sender
        answered = await loop_answer(command, self.submit, self.reply_timeout_s)
        return reply_to(answered, self.status())

    def _request(self, raw: bytes, credentials: tuple[int, int] | None) -> tuple[str, str] | dict:
        """The command line and who sent it, from a connection's line: a plain command (its sender the peer the
        kernel names), or ``relay {"sender": ..., "command": ...}`` from a process of the daemon's own user (the
        interfaces process, passing on a command from the web page or the 336 with its client); else the
        refusal."""
        who = describe_peer(credentials)
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            return {"ok": False, "message": "command is not UTF-8 text"}
        if not text.startswith("relay "):
            if len(raw) > MAX_LINE:
                return {"ok": False, "message": f"command longer than {MAX_LINE} bytes refused"}
            return text, who
        if credentials is None or credentials[1] not in (os.geteuid(), 0):
            return {"ok": False, "message": "relay refused: only the daemon's own user passes on commands of "
                                            "other clients"}
        try:
            relayed = json.loads(text[len("relay "):])
            command, sender = relayed["command"], relayed["sender"]
            if not isinstance(command, str) or not isinstance(sender, str):
                raise TypeError
        except (ValueError, KeyError, TypeError):
            return {"ok": False, "message": 'relay refused: give relay {"sender": "...", "command": "..."}'}
        if len(command.encode("utf-8")) > MAX_LINE or "\n" in command:
            return {"ok": False, "message": f"command longer than {MAX_LINE} bytes refused"}
        if len(sender) > MAX_SENDER or not sender.isprintable():
            return {"ok": False, "message": f"relay refused: a sender is printable text of at most {MAX_SENDER} "
                                            f"characters"}
        return command, f"{sender}; via {who}"

    @property
    def clients(self) -> int:
        """Connections open now."""
        return self.connections.open

    @property
    def most_clients(self) -> int:
        """The most connections open at once since the start."""
        return self.connections.most_seen

    async def _read_line(self, reader: asyncio.StreamReader, timeout_s: float) -> bytes | dict:
        """The client's line without its newline (its last bytes when it ends without one), or the refusal."""
        try:
            return (await asyncio.wait_for(reader.readuntil(b"\n"), timeout_s))[:-1]
        except asyncio.IncompleteReadError as ended:
            return ended.partial
        except asyncio.LimitOverrunError:
            return {"ok": False, "message": f"command longer than {MAX_LINE} bytes refused"}
        except asyncio.TimeoutError:
            return {"ok": False, "message": f"no complete command line within {timeout_s:g} s; "
                                            f"send one line ending in a newline"}

    def _busy(self, open_now: int) -> dict:
        return {"ok": False, "message": f"busy: {open_now} connections open at once (at most {self.max_clients} "
                                        f"for commands; beyond that only {RESERVED_FOR} is taken); "
                                        f"try again in a moment"}

    async def _serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        place = self.connections.arrived()
        open_now = self.connections.open
        reserved = place is not ConnectionBook.TAKEN
        try:
            if place is ConnectionBook.FULL:
                await self._send(writer, self._busy(open_now))
                return
            line = await self._read_line(reader, RESERVED_LINE_TIMEOUT_S if reserved else self.line_timeout_s)
            self.connections.request_received()
            request = line if isinstance(line, dict) else self._request(line, peer_credentials(writer))
            if isinstance(request, dict):
                reply = request
            else:
                text, sender = request
                words = text.split(maxsplit=1)
                if reserved and words[:1] != [RESERVED_FOR]:
                    reply = self._busy(open_now)
                elif words[:1] == ["subscribe"]:
                    subscribed = await self._subscribe(reader, writer, sender, words[1:])
                    if subscribed is None:      # served until it ended
                        return
                    reply = subscribed
                else:
                    reply = await self._reply_to_line(text, sender)
            await self._send(writer, reply)
        except asyncio.CancelledError:
            if self.connections.closed_for_room_now():
                message = (f"closed: no command line yet when the {self.connections.most_open} connections open "
                           f"at once were all taken; send the line as you connect")
            else:                               # the daemon is stopping: say so, without waiting for the client
                message = "the daemon is stopping; nothing more is answered"
            writer.write((json.dumps({"ok": False, "message": message}) + "\n").encode("utf-8"))
            writer.close()
        except Exception as error:              # one client's trouble never ends the socket
            log.warning("control socket: a client's command failed: %s: %s", type(error).__name__, error)
            await self._send(writer, {"ok": False, "message": f"internal error: {type(error).__name__}"})
        finally:
            self.connections.left()

    async def _subscribe(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, sender: str,
                         arguments: list[str]) -> dict | None:
        """``subscribe [SEQ]``: the live stream on this connection until it ends (None), or the refusal."""
        if self.stream is None:
            return {"ok": False, "message": "subscribe refused: this daemon serves no stream"}
        after = arguments[0].strip() if arguments else None
        if after is not None and not (after.isascii() and after.isdigit() and len(after) <= 18):
            return {"ok": False, "message": f"subscribe SEQ: SEQ is a whole number of events, got {after[:40]!r}"}
        return await self.stream.serve(reader, writer, sender, None if after is None else int(after))

    async def _send(self, writer: asyncio.StreamWriter, reply: dict) -> None:
        try:
            writer.write((json.dumps(finite_or_none(reply)) + "\n").encode("utf-8"))
            await asyncio.wait_for(writer.drain(), self.line_timeout_s)
        except (OSError, asyncio.TimeoutError):     # the client went away or does not read: nothing to tell
            pass
        finally:
            writer.close()

    # -- running ----------------------------------------------------------------------
    def start(self) -> None:
        """Bind (replacing a stale socket file, never another kind of file) and serve from a thread."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists() or self.path.is_symlink():
            if not stat.S_ISSOCK(self.path.lstat().st_mode):
                raise OSError(f"control socket path {self.path} exists and is not a socket; not replacing it")
            if _socket_answers(self.path):
                raise OSError(f"control socket {self.path} is in use by another running daemon")
            self.path.unlink()
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old_umask = os.umask(0o177)
        try:
            listener.bind(str(self.path))
        except OSError:
            listener.close()
            raise
        finally:
            os.umask(old_umask)
        try:
            os.chmod(self.path, self.mode)
            if self.owner or self.group:
                uid = pwd.getpwnam(self.owner).pw_uid if self.owner else -1
                gid = grp.getgrnam(self.group).gr_gid if self.group else -1
                os.chown(self.path, uid, gid)
            listener.listen(BACKLOG)
        except (OSError, KeyError):
            listener.close()
            self.path.unlink(missing_ok=True)
            raise
        self._clients.start(listener)
        log.info("control socket: %s (mode %o)", self.path, self.mode)

    def stop(self) -> None:
        """Stop serving (clients waiting for the loop's answer are told the daemon is stopping) and remove
        the socket file."""
        self._clients.stop()
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass


def peer_credentials(writer: asyncio.StreamWriter) -> tuple[int, int] | None:
    """(pid, uid) of the process at the other end of a Unix socket connection (the kernel's word: SO_PEERCRED)."""
    connection = writer.get_extra_info("socket")
    try:
        pid, uid, _ = struct.unpack("3i", connection.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                                                 struct.calcsize("3i")))
    except (AttributeError, OSError):
        return None
    return pid, uid


def describe_peer(credentials: tuple[int, int] | None) -> str:
    """``uid 1000 (alice), pid 4242`` for :func:`peer_credentials`."""
    if credentials is None:
        return "an unknown peer"
    pid, uid = credentials
    try:
        name = pwd.getpwuid(uid).pw_name
    except KeyError:
        name = "no user name"
    return f"uid {uid} ({name}), pid {pid}"


def peer(writer: asyncio.StreamWriter) -> str:
    """Who is at the other end of a Unix socket connection, in words."""
    return describe_peer(peer_credentials(writer))


def reply_to(command: Command, status: dict) -> dict:
    """The reply line's object for an answered command: ``ok``, ``message``, what else it answers, ``status``."""
    return {"ok": command.ok, "message": command.message, **(command.reply or {}), "status": status}


def _socket_answers(path: Path) -> bool:
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    probe.settimeout(0.5)
    try:
        probe.connect(str(path))
        return True
    except BlockingIOError:                     # a full backlog: someone is listening
        return True
    except OSError:
        return False
    finally:
        probe.close()


#: How long a client waits for the daemon in all (connecting, retrying while it is busy, the reply), s.
CLIENT_TIMEOUT_S = 10.0
#: First pause before asking a busy daemon again, and the longest, s.
BUSY_RETRY_FIRST_S = 0.05
BUSY_RETRY_LONGEST_S = 0.5


def is_busy(reply: dict) -> bool:
    """Whether ``reply`` is the daemon's ``busy`` refusal (too many connections at once: try again)."""
    return reply.get("ok") is False and str(reply.get("message", "")).startswith("busy:")


def send_command(path: Path, line: str, timeout_s: float = CLIENT_TIMEOUT_S,
                 on_busy: Callable[[str], None] | None = None) -> dict:
    """Client side: send one command line, return the daemon's reply.

    A daemon whose connection backlog is full is waited for, and one that answers ``busy`` is
    asked again (pauses from 50 ms to 0.5 s), both up to ``timeout_s`` in all. When the
    daemon refuses the line before reading all of it (a line too long) and closes, its reply
    is still read and returned.

    Parameters
    ----------
    path : pathlib.Path
        The control socket.
    line : str
        One command line (no line breaks inside).
    timeout_s : float
        For connecting, the replies and the retries in all, s.
    on_busy : callable, optional
        ``on_busy(message)`` once, at the first ``busy`` answer (``cryod ctl`` says it is retrying).

    Returns
    -------
    dict
        The reply: ``ok``, ``message`` and, for accepted commands, ``status``.

    Raises
    ------
    ValueError
        ``line`` holds a line break.
    ConnectionError
        No daemon listens at ``path``, it stayed busy, or it closed without a reply.
    """
    text = line.strip()
    if "\n" in text or "\r" in text:
        raise ValueError("a command is one line: it cannot hold a line break")
    deadline = time.monotonic() + timeout_s
    pause_s, attempts = BUSY_RETRY_FIRST_S, 0
    while True:
        reply = _exchange(path, text, deadline, timeout_s)
        attempts += 1
        if not is_busy(reply):
            return reply
        if time.monotonic() + pause_s > deadline:
            raise ConnectionError(f"the daemon at {path} stayed busy for {timeout_s:g} s ({attempts} attempts); "
                                  f"its last answer: {reply['message']}")
        if on_busy is not None and attempts == 1:
            on_busy(reply["message"])
        time.sleep(pause_s)
        pause_s = min(2.0 * pause_s, BUSY_RETRY_LONGEST_S)


def _exchange(path: Path, text: str, deadline: float, timeout_s: float) -> dict:
    """One connection: ``text`` out, the reply in (waiting for a full backlog until ``deadline``)."""
    while True:
        client = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        client.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            client.connect(str(path))
            break
        except (FileNotFoundError, ConnectionRefusedError) as error:
            client.close()
            raise ConnectionError(f"no cryod daemon listening at {path} ({error.strerror})") from None
        except PermissionError:
            client.close()
            raise ConnectionError(f"not allowed to use {path}: check control_socket.group/mode and your groups") \
                from None
        except BlockingIOError:                 # the backlog is full: the daemon is busy, wait for it
            client.close()
            if time.monotonic() >= deadline:
                raise ConnectionError(f"the daemon at {path} stayed busy for {timeout_s:g} s "
                                      f"(too many clients at once); try again") from None
            time.sleep(0.02)
    try:
        try:
            client.sendall((text + "\n").encode("utf-8"))
        except (BrokenPipeError, ConnectionResetError):
            pass                                # refused before reading it all: the reply says why
        try:
            raw = client.makefile("rb").readline()
        except ConnectionResetError:
            raw = b""
        except socket.timeout:
            raise ConnectionError(f"no reply from the daemon at {path} within {timeout_s:g} s") from None
    finally:
        client.close()
    if not raw:
        raise ConnectionError(f"the daemon at {path} closed the connection without a reply")
    try:
        return json.loads(raw.decode("utf-8"))
    except ValueError:
        raise ConnectionError(f"the reply from {path} is not a cryod reply: {raw[:80]!r}") from None
