"""One spelling for each instrument address, so that two spellings of one instrument compare equal.

A VISA resource is written many ways (``GPIB::16``, ``gpib0::16::INSTR``; ``TCPIP::Host::INSTR``
and ``TCPIP0::host::inst0::INSTR``); a serial device has names that are links to it
(``/dev/serial/by-id/...`` and ``/dev/ttyUSB0``). :func:`canonical_resource` gives pyvisa's
own normal form of a resource (:func:`pyvisa.rname.parse_resource_name`), with host names in
lower case, numbers without leading zeros and serial devices by their real path.
An instrument behind a Prologix controller is the controller plus its GPIB address
(:func:`canonical_prologix`). A host reached by a name in one place and by its IP address in
another is not recognised as the same: name each instrument one way everywhere.

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
"""

from __future__ import annotations

import os

from pyvisa import rname

#: Fields of a parsed resource that are whole numbers (written without leading zeros).
_NUMBER_FIELDS = ("board", "primary_address", "secondary_address", "port", "usb_interface_number")
#: Fields of a parsed resource that are hexadecimal numbers (USB vendor and model).
_HEX_FIELDS = ("manufacturer_id", "model_code")


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


__all__ = ["canonical_resource", "canonical_serial_port", "canonical_prologix_adapter", "canonical_prologix"]
