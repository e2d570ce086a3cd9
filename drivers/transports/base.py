"""The one interface between a driver and the wire: :class:`Transport`.

A driver writes SCPI text and reads replies; it does not care whether they
travel over a GPIB card, a Prologix adapter, a TCP socket, a serial line or a
function call into a simulated instrument. Every transport:

* sends one program message per :meth:`~Transport.write` (terminator added),
* returns one reply per :meth:`~Transport.read`, terminator stripped,
* raises :class:`drivers.errors.InstrumentTimeout` when no reply comes within
  ``timeout_s`` and :class:`drivers.errors.ConnectionLost` when the
  connection is gone, after which :meth:`~Transport.reopen` may recover it,
* :meth:`~Transport.trigger` sends a trigger to this one device: the GPIB
  group execute trigger (GET) where the bus has one, else ``*TRG``, which
  IEEE 488.2 (section 10.37) defines as its equivalent.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable


@runtime_checkable
class Transport(Protocol):
    """A connection to one instrument."""

    #: Where the instrument is (resource name or description), for error messages.
    name: str
    #: Longest wait for a reply (s); may be set at any time and holds from then on (a caller may wait
    #: less for a reading than for a configuration to be taken in).
    timeout_s: float

    def write(self, command: str) -> None:
        """Send one program message."""

    def read(self) -> str:
        """Receive one reply (terminator stripped)."""

    def query(self, command: str) -> str:
        """Send a query and receive its reply."""

    def trigger(self) -> None:
        """Trigger this device (GPIB GET, or ``*TRG`` where there is no GET)."""

    def close(self) -> None:
        """Release the connection."""

    def reopen(self) -> None:
        """Close and open the connection again (after :class:`ConnectionLost`)."""
