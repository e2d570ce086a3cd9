"""Where an instrument is: its bus and its address on that bus, written one way.

Two spellings of one place compare equal: ``GPIB::16::INSTR`` and ``GPIB0::16::INSTR`` are both
address 16 on GPIB board 0; a Prologix controller on ``/dev/serial/by-id/usb-Prologix...`` and
on ``/dev/ttyUSB0`` are the same controller when the first is a link to the second. A GPIB
instrument is at its primary address (0 to 30) on its bus, a GPIB card or a Prologix
controller; a secondary address selects a function inside it, so it does not make another place.

VISA resource names are read by PyVISA's own parser (:func:`pyvisa.rname.parse_resource_name`);
what it leaves as text (the board, the addresses, the port) is checked here, since a GPIB address
of 61 or ``16:INSTR`` would otherwise only fail when the instrument is opened.

Examples
--------
>>> str(resource_location("GPIB::16::INSTR"))
'GPIB0 address 16'
>>> resource_location("GPIB0::16::INSTR") == resource_location("GPIB0::16::2::INSTR")
True
>>> str(resource_location("TCPIP0::192.168.1.20::1234::SOCKET"))
'TCP 192.168.1.20 port 1234'
>>> str(prologix_location(host="192.168.1.40", gpib_address=12))
'Prologix 192.168.1.40 address 12'
>>> resource_location("GPIB0::61::INSTR")
Traceback (most recent call last):
...
ValueError: the primary address must be a whole number 0 to 30, got '61' (syntax: GPIB[board]::primary address[::secondary address][::INSTR])
"""

from __future__ import annotations

import ipaddress
import os
import re
from dataclasses import dataclass

from pyvisa import rname

#: GPIB primary and secondary addresses (IEEE 488.1): 0 to 30.
GPIB_ADDRESSES = range(0, 31)
#: A host name: dot-separated labels of letters, digits and inner hyphens (RFC 1123), 253 characters at most.
_HOST_NAME = re.compile(r"(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
                        r"(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*\.?", re.ASCII)
#: The resource classes an instrument is opened as: a message-based instrument or a raw TCP socket.
INSTRUMENT_CLASSES = ("INSTR", "SOCKET")


@dataclass(frozen=True)
class InstrumentLocation:
    """An instrument's bus and its address on the bus; ``str()`` reads ``GPIB0 address 16``.

    Attributes
    ----------
    bus : str
        ``GPIB0`` (a GPIB card), ``Prologix /dev/ttyUSB0``, ``TCP 10.0.0.2 port 1234``, ``serial /dev/ttyS0``, ...
    address : str
        The GPIB primary address on the bus, or empty where the bus holds one instrument.
    """

    bus: str
    address: str = ""

    def __str__(self) -> str:
        return f"{self.bus} address {self.address}" if self.address else self.bus


def _whole_number(text: str | None, what: str, allowed: range | None = None) -> int:
    if text is None or not text.isascii() or not text.isdigit() or (allowed is not None
                                                                     and int(text) not in allowed):
        limits = f" {allowed.start} to {allowed.stop - 1}" if allowed is not None else ""
        raise ValueError(f"the {what} must be a whole number{limits}, got {text!r}")
    return int(text)


def _host(host: str) -> str:
    """A host name or IP address as written (lower case); ValueError when it can be neither."""
    try:
        return str(ipaddress.ip_address(host))
    except ValueError:
        pass
    if ":" in host:
        raise ValueError(f"the host {host!r} looks like an IPv6 address, which a VISA resource name cannot hold: give "
                         f"a host name for it, or an IPv4 address")
    if re.fullmatch(r"[0-9.]+", host):
        raise ValueError(f"the host {host!r} is not an IPv4 address (four numbers 0 to 255)")
    if not _HOST_NAME.fullmatch(host):
        raise ValueError(f"the host {host!r} is neither a host name nor an IP address")
    return host.lower()


def _device(path: str) -> str:
    """A device path with its links resolved (``/dev/serial/by-id/...`` names the ``/dev/ttyUSB`` it links to)."""
    return os.path.realpath(path) if path.startswith("/") else path


def resource_location(resource: str) -> InstrumentLocation:
    """Where the VISA resource ``resource`` is (one instrument: an INSTR or SOCKET resource).

    Raises
    ------
    ValueError
        PyVISA cannot parse the name, it names an interface rather than an instrument, or a
        number in it is not one (a GPIB address outside 0..30, a TCP port outside 1..65535);
        the message gives the syntax of the resource's kind.
    """
    try:
        parsed = rname.parse_resource_name(resource)
    except rname.InvalidResourceName as error:
        raise ValueError(str(error)) from None
    syntax = getattr(type(parsed), "_visa_syntax", "")
    if parsed.resource_class not in INSTRUMENT_CLASSES:
        raise ValueError(f"{parsed.resource_class} is an interface, not an instrument: give one instrument's "
                         f"resource (e.g. GPIB0::16::INSTR, TCPIP0::10.0.0.2::1234::SOCKET)")
    try:
        if isinstance(parsed, rname.GPIBInstr):
            board = _whole_number(parsed.board, "GPIB board")
            primary = _whole_number(parsed.primary_address, "primary address", GPIB_ADDRESSES)
            if parsed.secondary_address is not None:
                _whole_number(parsed.secondary_address, "secondary address", GPIB_ADDRESSES)
            return InstrumentLocation(f"GPIB{board}", str(primary))
        if isinstance(parsed, rname.TCPIPSocket):
            port = _whole_number(parsed.port, "TCP port", range(1, 65536))
            return InstrumentLocation(f"TCP {_host(parsed.host_address)} port {port}")
        if isinstance(parsed, rname.TCPIPInstr):
            return InstrumentLocation(f"VXI-11 {_host(parsed.host_address)} device {parsed.lan_device_name}")
        if isinstance(parsed, rname.ASRLInstr):
            return InstrumentLocation(f"serial {_device(parsed.board)}")
    except ValueError as error:
        raise ValueError(f"{error} (syntax: {syntax})" if syntax else str(error)) from None
    return InstrumentLocation(str(parsed))


def prologix_location(port: str | None = None, host: str | None = None, gpib_address: int = 0) -> InstrumentLocation:
    """Where an instrument behind a Prologix controller is: the controller (serial ``port`` or ``host``) and
    the GPIB address.

    Raises
    ------
    ValueError
        ``host`` is neither a host name nor an IP address.
    """
    from drivers.transports.prologix import interface_resource_name

    name = interface_resource_name(serial_port=port, host=host)
    try:
        rname.parse_resource_name(name)
    except rname.InvalidResourceName as error:
        raise ValueError(f"{port if port is not None else host!r} cannot be written in a VISA resource name ({error})") \
            from None
    bus = f"Prologix {_device(port)}" if port is not None else f"Prologix {_host(str(host))}"
    return InstrumentLocation(bus, str(gpib_address))


def serial_device(resource: str) -> str | None:
    """The serial device file of an ``ASRL/dev/...::INSTR`` resource, or None for other resources."""
    try:
        parsed = rname.parse_resource_name(resource)
    except rname.InvalidResourceName:
        return None
    if isinstance(parsed, rname.ASRLInstr) and parsed.board.startswith("/"):
        return parsed.board
    return None


__all__ = ["InstrumentLocation", "resource_location", "prologix_location", "serial_device", "GPIB_ADDRESSES"]
