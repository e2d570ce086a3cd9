"""One spelling for each instrument address, so that two spellings of one instrument compare equal.

A VISA resource is written many ways (``GPIB::16``, ``gpib0::16::INSTR``; ``TCPIP::Host::INSTR``
and ``TCPIP0::host::inst0::INSTR``); a serial device has names that are links to it
(``/dev/serial/by-id/...`` and ``/dev/ttyUSB0``). :func:`canonical_resource` gives pyvisa's
own normal form of a resource (:func:`pyvisa.rname.parse_resource_name`), with host names in
lower case, numbers without leading zeros and serial devices by their real path.
An instrument behind a Prologix controller is the controller plus its GPIB address
(:func:`canonical_prologix`). A host reached by a name in one place and by its IP address in
another is not recognised as the same: name each instrument one way everywhere.

What pyvisa's parser leaves as text is checked by :func:`instrument_resource` and
:func:`prologix_instrument` before an address is used: a GPIB address outside 0..30
(``GPIB0::61::INSTR``), a TCP port outside 1..65535, a host that is neither a host name nor an IP
address, an interface where an instrument belongs (``GPIB0::INTFC``), a controller that cannot be
named in a VISA resource; otherwise these would only fail when the instrument is opened.

Examples
--------
>>> canonical_resource("gpib::16")
'GPIB0::16::INSTR'
>>> canonical_resource("TCPIP::Cryo-Bench.lab::5025::SOCKET")
'TCPIP0::cryo-bench.lab::5025::SOCKET'
>>> canonical_prologix(host="192.168.1.40", gpib_address=12)
'prologix-ethernet:192.168.1.40:gpib12'
>>> canonical_resource("GPIB0::sixteen::INSTR")
Traceback (most recent call last):
...
ValueError: 'GPIB0::sixteen::INSTR' is not a VISA resource name: the GPIB primary address must be a number
>>> instrument_resource("GPIB0::61::INSTR")
Traceback (most recent call last):
...
ValueError: 'GPIB0::61::INSTR': the GPIB primary address must be 0 to 30, got 61
"""

from __future__ import annotations

import ipaddress
import os
import re

from pyvisa import rname

#: Fields of a parsed resource that are whole numbers (written without leading zeros).
_NUMBER_FIELDS = ("board", "primary_address", "secondary_address", "port", "usb_interface_number")
#: Fields of a parsed resource that are hexadecimal numbers (USB vendor and model).
_HEX_FIELDS = ("manufacturer_id", "model_code")
#: GPIB primary and secondary addresses (IEEE 488.1): 0 to 30.
GPIB_ADDRESSES = range(0, 31)
#: The resource classes an instrument is opened as: a message-based instrument or a raw TCP socket.
INSTRUMENT_CLASSES = ("INSTR", "SOCKET")
#: A host name: dot-separated labels of letters, digits and inner hyphens (RFC 1123), 253 characters at most.
_HOST_NAME = re.compile(r"(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?"
                        r"(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*\.?", re.ASCII)


def canonical_resource(resource: str) -> str:
    """The normal form of a VISA resource name.

    Raises
    ------
    ValueError
        ``resource`` is not a VISA resource name (the message says why).
    """
    text = str(resource).strip()
    try:
        parsed = rname.parse_resource_name(text)
    except rname.InvalidResourceName as error:
        raise ValueError(f"{text!r} is not a VISA resource name: {error}") from None
    fields = {name: getattr(parsed, name) for name in parsed._fields}
    for name in _NUMBER_FIELDS:
        value = fields.get(name)
        if value is not None and str(value).isdigit():
            fields[name] = str(int(value))
        elif value is not None and name != "board":
            raise ValueError(f"{text!r} is not a VISA resource name: the {parsed.interface_type} "
                             f"{name.replace('_', ' ')} must be a number")
    for name in _HEX_FIELDS:
        if fields.get(name) is not None:
            try:
                fields[name] = f"0x{int(fields[name], 0):04X}"
            except ValueError:
                raise ValueError(f"{text!r} is not a VISA resource name: the USB {name.replace('_', ' ')} "
                                 f"must be a number") from None
    if fields.get("host_address") is not None:
        fields["host_address"] = fields["host_address"].lower()
    if parsed.interface_type == "ASRL" and str(fields["board"]).startswith("/"):
        fields["board"] = os.path.realpath(fields["board"])
    return str(type(parsed)(**fields))


def canonical_serial_port(port: str) -> str:
    """A serial device by its real path (``/dev/serial/by-id/...`` links resolved); a COM name in capitals."""
    text = str(port).strip()
    return os.path.realpath(text) if text.startswith("/") else text.upper()


def canonical_prologix_adapter(*, port: str | None = None, host: str | None = None) -> str:
    """A Prologix controller: its serial device (GPIB-USB) or its host (GPIB-ETHERNET)."""
    if (port is None) == (host is None):
        raise ValueError("a Prologix controller has either a serial port or a host")
    if port is not None:
        return f"prologix-usb:{canonical_serial_port(port)}"
    return f"prologix-ethernet:{str(host).strip().lower()}"


def canonical_prologix(*, port: str | None = None, host: str | None = None, gpib_address: int) -> str:
    """An instrument behind a Prologix controller: the controller and the GPIB address."""
    return f"{canonical_prologix_adapter(port=port, host=host)}:gpib{int(gpib_address)}"


def _host_problem(host: str) -> str | None:
    """Why ``host`` can be neither a host name nor an IP address in a VISA resource, or None."""
    try:
        ipaddress.ip_address(host)
    except ValueError:
        pass
    else:
        return ("an IPv6 address, which a VISA resource name cannot hold: give a host name for it, or an IPv4 "
                "address") if ":" in host else None
    if re.fullmatch(r"[0-9.]+", host):
        return "not an IPv4 address (four numbers 0 to 255)"
    if not _HOST_NAME.fullmatch(host):
        return "neither a host name nor an IP address"
    return None


def instrument_resource(resource: str) -> str:
    """The canonical form of one instrument's VISA resource, its addresses checked.

    Raises
    ------
    ValueError
        ``resource`` is not a VISA resource name, names an interface rather than an instrument
        (an ``INSTR`` or ``SOCKET`` resource), or holds a GPIB address outside 0..30, a TCP port
        outside 1..65535 or a host that is neither a host name nor an IP address.
    """
    canonical = canonical_resource(resource)
    parsed = rname.parse_resource_name(canonical)
    problem = None
    if parsed.resource_class not in INSTRUMENT_CLASSES:
        problem = (f"{parsed.resource_class} is an interface, not an instrument: give one instrument's resource "
                   f"(e.g. GPIB0::16::INSTR, TCPIP0::10.0.0.2::1234::SOCKET)")
    elif isinstance(parsed, rname.GPIBInstr):
        for name, value in (("primary", parsed.primary_address), ("secondary", parsed.secondary_address)):
            if value is not None and int(value) not in GPIB_ADDRESSES:
                problem = f"the GPIB {name} address must be 0 to 30, got {value}"
    elif isinstance(parsed, (rname.TCPIPSocket, rname.TCPIPInstr)):
        host_problem = _host_problem(parsed.host_address)
        if host_problem is not None:
            problem = f"the host {parsed.host_address!r} is {host_problem}"
        elif isinstance(parsed, rname.TCPIPSocket) and not 1 <= int(parsed.port) <= 65535:
            problem = f"the TCP port must be 1 to 65535, got {parsed.port}"
    if problem is not None:
        raise ValueError(f"{str(resource).strip()!r}: {problem}")
    return canonical


def prologix_instrument(*, port: str | None = None, host: str | None = None, gpib_address: int) -> str:
    """:func:`canonical_prologix`, once the controller's serial port or host can be named in a VISA resource.

    Raises
    ------
    ValueError
        A host that is neither a host name nor an IPv4 address, or a port pyvisa cannot parse in a
        resource name.
    """
    from drivers.transports.prologix import interface_resource_name

    if host is not None and _host_problem(host) is not None:
        raise ValueError(f"the host {host!r} is {_host_problem(host)}")
    try:
        rname.parse_resource_name(interface_resource_name(serial_port=port, host=host))
    except rname.InvalidResourceName as error:
        raise ValueError(f"{port if port is not None else host!r} cannot be named in a VISA resource: {error}") \
            from None
    return canonical_prologix(port=port, host=host, gpib_address=gpib_address)


def network_host(resource: str) -> str | None:
    """The host of a ``TCPIP...`` resource (a name or an IP address), or None for other resources.

    >>> network_host("TCPIP0::cryo-bench.lab::5025::SOCKET")
    'cryo-bench.lab'
    >>> network_host("GPIB0::16::INSTR") is None
    True
    """
    try:
        parsed = rname.parse_resource_name(resource)
    except rname.InvalidResourceName:
        return None
    return parsed.host_address if isinstance(parsed, (rname.TCPIPInstr, rname.TCPIPSocket)) else None


def serial_device(resource: str) -> str | None:
    """The serial device file of an ``ASRL/dev/...::INSTR`` resource, or None for other resources."""
    try:
        parsed = rname.parse_resource_name(resource)
    except rname.InvalidResourceName:
        return None
    if isinstance(parsed, rname.ASRLInstr) and str(parsed.board).startswith("/"):
        return parsed.board
    return None


__all__ = ["canonical_resource", "canonical_serial_port", "canonical_prologix_adapter", "canonical_prologix",
           "instrument_resource", "prologix_instrument", "network_host", "serial_device", "GPIB_ADDRESSES"]
