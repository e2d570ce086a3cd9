"""Instruments reached through PyVISA: GPIB cards, TCP sockets, serial lines.

``VisaTransport("GPIB0::16::INSTR")`` opens the resource with PyVISA and
reads and writes lines. The VISA library is pyvisa-py (``'@py'``) unless
asked otherwise: pass ``visa_library='@ivi'`` to use an installed NI-VISA
(or Keysight IO Libraries) — the GPIB cards of National Instruments need it
unless linux-gpib is installed for pyvisa-py.

Resource names (PyVISA documentation, "Resource names"):

* ``GPIB0::16::INSTR``: instrument at primary address 16 on GPIB board 0;
* ``TCPIP0::192.168.1.20::1234::SOCKET``: a raw TCP socket (the simulated
  instruments' server, LAN-to-GPIB gateways); line termination ``\\n``;
* ``ASRL/dev/ttyUSB0::INSTR`` (``ASRL3::INSTR`` on Windows): a serial port;
  baud rate and framing as keyword options (``baud_rate=9600``).

What PyVISA raises is turned into the typed errors of :mod:`drivers.errors`:
a VISA timeout is :class:`~drivers.errors.InstrumentTimeout`; a closed or
reset connection is :class:`~drivers.errors.ConnectionLost`; a reply that is
not text is :class:`~drivers.errors.BadReply`. pyvisa-py reports a TCP peer
that closed its socket as a timeout; the transport then looks at the socket
and reports the loss instead.
"""

from __future__ import annotations

import socket
from typing import Any

import pyvisa
from pyvisa import constants, rname
from pyvisa.errors import VisaIOError

from drivers.errors import BadReply, ConnectionLost, InstrumentTimeout

_resource_managers: dict[str, pyvisa.ResourceManager] = {}

_CONNECTION_LOST_CODES = {
    constants.StatusCode.error_connection_lost,
    constants.StatusCode.error_io,
    constants.StatusCode.error_invalid_object,
    constants.StatusCode.error_resource_not_found,
    constants.StatusCode.error_closing_failed,
}


def resource_manager(visa_library: str = "@py") -> pyvisa.ResourceManager:
    """The PyVISA resource manager of ``visa_library`` (one per library and process)."""
    if visa_library not in _resource_managers:
        _resource_managers[visa_library] = pyvisa.ResourceManager(visa_library)
    return _resource_managers[visa_library]


def missing_support(resource_name: str, visa_library: str = "@py") -> str | None:
    """Why ``visa_library`` cannot reach ``resource_name`` on this computer (a package it lacks), or None.

    pyvisa-py keeps a list of the kinds of resource it can open, and of those it cannot open here
    and why (its sessions whose Python binding is not installed: linux-gpib or gpib-ctypes for a
    GPIB card, PyUSB for USB); an instrument on a GPIB card needs the card's interface too. Other
    VISA libraries say nothing in advance: None.
    """
    if visa_library != "@py":
        return None
    resource_manager(visa_library)                # loads pyvisa-py, which registers its sessions
    from pyvisa_py.sessions import Session

    issues = dict(Session.iter_session_classes_issues())
    parsed = rname.parse_resource_name(resource_name)
    try:
        Session.get_session_class(parsed.interface_type_const, parsed.resource_class)
    except ValueError:
        return f"pyvisa-py has no support for {parsed.interface_type} {parsed.resource_class} resources"
    for needed in ((parsed.interface_type_const, parsed.resource_class), (parsed.interface_type_const, "INTFC")):
        if needed in issues:
            return str(issues[needed]).strip().splitlines()[0]
    return None


#: How long a late reply is waited for, to be dropped, before the query after a timeout (s).
LATE_REPLY_WINDOW_S = 0.05


def peer_closed(resource: Any) -> bool:
    """True when the TCP peer has closed the socket under ``resource`` (pyvisa-py sessions only)."""
    sessions = getattr(getattr(resource, "visalib", None), "sessions", {})
    sock = _socket_of(sessions.get(getattr(resource, "session", None)))
    if sock is None:
        return False
    try:
        return sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True


def _socket_of(session: Any) -> socket.socket | None:
    """The TCP socket under a pyvisa-py session (through a Prologix interface if needed)."""
    for _ in range(3):
        candidate = getattr(session, "interface", None)
        if isinstance(candidate, socket.socket):
            return candidate
        session = candidate
    return None


def send_without_delay(resource: Any) -> None:
    """Turn off Nagle's algorithm on a TCP resource: each SCPI line leaves at once.

    Without it a short command written right after another waits for the
    peer's delayed acknowledgement (about 40 ms on Linux), longer than half a
    cryod cycle. VISA's ``VI_ATTR_TCPIP_NODELAY`` does it where the library
    supports setting it (NI-VISA); pyvisa-py 0.8 refuses to set the attribute,
    so the option goes on its socket directly.
    """
    try:
        resource.set_visa_attribute(constants.ResourceAttribute.tcpip_nodelay, constants.VisaBoolean.true)
        return
    except Exception:  # noqa: BLE001 - pyvisa-py raises its own UnknownAttribute here; fall back below
        pass
    sessions = getattr(getattr(resource, "visalib", None), "sessions", {})
    sock = _socket_of(sessions.get(getattr(resource, "session", None)))
    if sock is not None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


class VisaTransport:
    """A :class:`~drivers.transports.base.Transport` over a PyVISA message-based resource.

    Parameters
    ----------
    resource_name : str
        VISA resource name, e.g. ``GPIB0::16::INSTR`` or ``TCPIP0::127.0.0.1::5025::SOCKET``.
    visa_library : str
        ``'@py'`` (pyvisa-py, default) or ``'@ivi'`` (NI-VISA / Keysight VISA).
    timeout_s : float
        Longest wait for a reply, and for a connection to open (s); may be changed at any time.
    read_termination, write_termination : str or None
        Line terminators (the Keithleys answer with LF; GPIB also asserts EOI). None leaves
        the session's own (a Prologix session ends reads at the LF the instrument sends).
    name : str, optional
        Description for error messages (default: the resource name).
    resource_manager : pyvisa.ResourceManager, optional
        Use this one instead of the library's shared one.
    **resource_options
        Further attributes for ``open_resource`` (serial: ``baud_rate``, ``data_bits`` ...).
    """

    def __init__(self, resource_name: str, *, visa_library: str = "@py", timeout_s: float = 1.0,
                 read_termination: str | None = "\n", write_termination: str | None = "\n",
                 name: str | None = None,
                 resource_manager: pyvisa.ResourceManager | None = None, **resource_options: Any):
        self.resource_name = resource_name
        self.name = name or resource_name
        self._manager = resource_manager
        self._visa_library = visa_library
        self._timeout_s = float(timeout_s)
        self._options = dict(resource_options)
        for key, termination in (("read_termination", read_termination),
                                 ("write_termination", write_termination)):
            if termination is not None:
                self._options[key] = termination
        parsed = rname.parse_resource_name(resource_name)
        self.is_gpib_instrument = (parsed.interface_type_const == constants.InterfaceType.gpib
                                   and parsed.resource_class == "INSTR")
        self.is_socket = parsed.resource_class == "SOCKET"
        #: Look at the socket before each operation (see :class:`PrologixInstrument`).
        self.check_peer_before_io = False
        self.resource: Any = None
        self._reply_owed = False             # a read timed out: its reply may still arrive
        self._open()

    # -- connection --------------------------------------------------------------
    @property
    def manager(self) -> pyvisa.ResourceManager:
        if self._manager is None:
            self._manager = resource_manager(self._visa_library)
        return self._manager

    def _open(self) -> None:
        try:
            self.resource = self.manager.open_resource(self.resource_name, timeout=self._timeout_s * 1000.0,
                                                       open_timeout=round(self._timeout_s * 1000.0), **self._options)
        except Exception as error:  # noqa: BLE001 - pyvisa-py raises a bare Exception for a host it cannot resolve
            self.resource = None
            raise ConnectionLost(self.name, f"cannot open {self.resource_name}: {error}") from error
        if self.is_socket:
            send_without_delay(self.resource)

    def close(self) -> None:
        resource, self.resource = self.resource, None
        if resource is not None:
            try:
                resource.close()
            except (VisaIOError, OSError):
                pass

    def reopen(self) -> None:
        self.close()
        self._reply_owed = False             # a new connection holds no old reply
        self._open()

    @property
    def timeout_s(self) -> float:
        return self._timeout_s

    @timeout_s.setter
    def timeout_s(self, value: float) -> None:
        self._timeout_s = float(value)
        self._wait_for_replies(self._timeout_s)

    def _wait_for_replies(self, timeout_s: float) -> None:
        """Set the wait for a reply on the session replies are read through."""
        if self.resource is not None:
            self.resource.timeout = timeout_s * 1000.0

    # -- I/O ------------------------------------------------------------------------
    def _io(self, method: str, *arguments: Any) -> Any:
        """Call the resource's ``method``, turning PyVISA's errors into typed instrument errors."""
        if self.resource is None:
            raise ConnectionLost(self.name, "connection is closed (reopen it)")
        if self.check_peer_before_io and peer_closed(self.resource):
            raise ConnectionLost(self.name, "the other end closed the connection")
        try:
            return getattr(self.resource, method)(*arguments)
        except VisaIOError as error:
            if error.error_code == constants.StatusCode.error_timeout:
                if peer_closed(self.resource):
                    raise ConnectionLost(self.name, "the instrument closed the connection") from error
                raise InstrumentTimeout(self.name, f"no reply within {self.timeout_s:g} s") from error
            if error.error_code in _CONNECTION_LOST_CODES:
                raise ConnectionLost(self.name, f"connection failed: {error.description}") from error
            raise ConnectionLost(self.name, f"VISA error {error.abbreviation}: {error.description}") from error
        except UnicodeDecodeError as error:
            raise BadReply(self.name, "reply is not ASCII text", reply=repr(error.object)) from error
        except OSError as error:
            raise ConnectionLost(self.name, f"connection failed: {error}") from error

    def write(self, command: str) -> None:
        self._io("write", command)

    def read(self) -> str:
        try:
            return self._io("read").strip()
        except InstrumentTimeout:
            self._reply_owed = True          # it may still come, and would pass for the next query's
            raise

    def query(self, command: str) -> str:
        if self._reply_owed:
            self.discard_late_replies()
        self.write(command)
        return self.read()

    def discard_late_replies(self, window_s: float = LATE_REPLY_WINDOW_S) -> list[str]:
        """Read and drop what arrives within ``window_s``: the reply to a query that timed out.

        Called before the next query after a read timed out, so that a reply that came late is not
        taken for the answer to that query (a heater-off confirmed by ``0,"No error"``). Returns
        what was dropped.
        """
        self._reply_owed = False
        dropped: list[str] = []
        if self.resource is None:
            return dropped
        self._wait_for_replies(window_s)
        try:
            while len(dropped) < 16:
                try:
                    dropped.append(self.resource.read().strip())
                except (VisaIOError, OSError, UnicodeDecodeError):
                    break
        finally:
            self._wait_for_replies(self._timeout_s)
        return dropped

    def trigger(self) -> None:
        """GPIB GET to this device (VISA ``viAssertTrigger``); ``*TRG`` on other interfaces."""
        if self.is_gpib_instrument:
            self._io("assert_trigger")
        else:
            self.write("*TRG")

    def clear(self) -> None:
        """Selected device clear (GPIB SDC): empties the instrument's input and output buffers."""
        self._io("clear")
