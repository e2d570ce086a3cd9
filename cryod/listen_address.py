"""Addresses the daemon's network interfaces listen on: ``host:port``, loopback unless stated otherwise.

Every TCP interface of the daemon (the Prometheus endpoint, the web page, the Lake Shore 336
command set) is given as ``host:port`` in its configuration section. The host must be written
out: an IP address (``127.0.0.1``, ``0.0.0.0`` for every interface, ``192.168.1.20``, ``[::1]``)
or ``localhost``. A host that is not loopback opens the interface to other computers; the
configuration must say so in the address itself, and the daemon says it again in the journal
at start (:func:`describe`).

Examples
--------
>>> parse_address("127.0.0.1:9477")
('127.0.0.1', 9477)
>>> is_loopback("127.0.0.1"), is_loopback("0.0.0.0"), is_loopback("localhost")
(True, False, True)
>>> describe("Lake Shore 336 command set", "0.0.0.0", 7777)
'Lake Shore 336 command set on 0.0.0.0:7777: NOT loopback, reachable from other computers'
"""

from __future__ import annotations

import ipaddress


def parse_address(text: str, allow_any_port: bool = False, host_names: bool = False) -> tuple[str, int]:
    """``host:port`` (``[v6]:port`` for IPv6) as (host, port); ValueError says what is wrong.

    Parameters
    ----------
    text : str
    allow_any_port : bool
        Accept port 0 (the system picks a free port; tests).
    host_names : bool
        Accept any host name (the metrics endpoint's ``metrics.address``), not only an IP address
        or ``localhost``.

    Raises
    ------
    ValueError
        Not ``host:port``, an empty host, a host that is neither an IP address nor ``localhost``
        (unless ``host_names``), or a port outside 1..65535.
    """
    host, separator, port = str(text).rpartition(":")
    if not separator or not host:
        raise ValueError(f"{text!r} is not host:port (for example 127.0.0.1:9477)")
    if not port.isascii() or not port.isdigit() or not (0 if allow_any_port else 1) <= int(port) <= 65535:
        raise ValueError(f"{text!r}: the port must be a number from 1 to 65535")
    host = host.strip("[]")
    if host != "localhost" and not host_names:
        try:
            ipaddress.ip_address(host)
        except ValueError:
            raise ValueError(f"{text!r}: the host must be an IP address (127.0.0.1 for this computer only, "
                             f"0.0.0.0 for every interface) or localhost") from None
    return host, int(port)


def is_loopback(host: str) -> bool:
    """Whether ``host`` reaches this computer only."""
    return host == "localhost" or ipaddress.ip_address(host).is_loopback


def describe(what: str, host: str, port: int) -> str:
    """The journal's line for an interface listening at ``host:port``, saying when it is not loopback."""
    where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    if is_loopback(host):
        return f"{what} on {where} (this computer only)"
    return f"{what} on {where}: NOT loopback, reachable from other computers"
