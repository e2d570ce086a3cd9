"""Prologix GPIB-USB and GPIB-ETHERNET controllers: one adapter, several instruments.

Many labs drive their GPIB instruments through a Prologix controller instead
of a GPIB card: the GPIB-USB one appears as a serial port (pyserial), the
GPIB-ETHERNET one listens on TCP port 1234. pyvisa-py (0.8 and later)
already speaks the Prologix protocol (``pyvisa_py/prologix.py``): it opens
the controller as ``PRLGX-ASRL0::/dev/ttyUSB0::INTFC`` or
``PRLGX-TCPIP0::<host>::1234::INTFC``, sets it up (``++mode 1``,
``++auto 0``, ``++eos 3``, ``++eoi 1``, ``++eot_enable 0``,
``++read_tmo_ms``) and then serves ``GPIB0::<address>::INSTR`` resources
through it, sending ``++addr <address>`` whenever another instrument is
addressed, escaping ESC, CR, LF and ``+`` in data, ``++read eoi`` to read
and ``++trg`` for a trigger. That code is used here as it is; what this
module adds is the group trigger of several addresses, which the
controller does in one command (Prologix GPIB-USB/-ETHERNET Controller User
Manual, section 8.20 / 9.20 ``trg``: "++trg [PAD1 [SAD1] PAD2 [SAD2] …
PAD15 [SAD15]]" issues Group Execute Trigger to the listed instruments),
and recovery of a dropped controller connection.

The controller's timeout governs every instrument behind it: pyvisa-py
reads through the controller's interface session, so setting an
instrument's ``timeout_s`` sets the controller's.

Examples
--------
>>> adapter = PrologixAdapter.ethernet("192.168.1.50")        # doctest: +SKIP
>>> flange_dmm = adapter.instrument(16, name="flange DMM")      # doctest: +SKIP
>>> stage_dmm = adapter.instrument(17, name="PTC-stage DMM")   # doctest: +SKIP
>>> adapter.trigger([16, 17])                                   # doctest: +SKIP
"""

from __future__ import annotations

import threading
from typing import Any, Sequence

import pyvisa
from pyvisa import rname
from pyvisa.errors import VisaIOError

from drivers.errors import ConnectionLost
from drivers.transports.visa import VisaTransport, peer_closed, resource_manager, send_without_delay

#: TCP port of the Prologix GPIB-ETHERNET controller (its manual, section 5).
ETHERNET_PORT = 1234


def interface_resource_name(serial_port: str | None = None, host: str | None = None, port: int = ETHERNET_PORT,
                            board: int = 0) -> str:
    """pyvisa-py's resource name of a Prologix controller on ``serial_port`` (GPIB-USB) or at ``host``
    (GPIB-ETHERNET).

    Examples
    --------
    >>> interface_resource_name(serial_port="/dev/ttyUSB0"), interface_resource_name(host="10.0.0.9")
    ('PRLGX-ASRL0::/dev/ttyUSB0::INTFC', 'PRLGX-TCPIP0::10.0.0.9::1234::INTFC')
    """
    if serial_port is not None:
        device = serial_port[3:] if serial_port.upper().startswith("COM") else serial_port
        return f"PRLGX-ASRL{board}::{device}::INTFC"
    return f"PRLGX-TCPIP{board}::{host}::{port}::INTFC"


class PrologixAdapter:
    """One Prologix controller and the GPIB instruments behind it.

    Parameters
    ----------
    interface_resource_name : str
        ``PRLGX-TCPIP<board>::<host>::<port>::INTFC`` or ``PRLGX-ASRL<board>::<device>::INTFC``;
        :meth:`usb` and :meth:`ethernet` build it.
    timeout_s : float
        Longest wait for a reply from any instrument behind the controller (s).
    resource_manager : pyvisa.ResourceManager, optional
        A pyvisa-py resource manager (the shared ``'@py'`` one by default).
    """

    def __init__(self, interface_resource_name: str, *, timeout_s: float = 1.0,
                 resource_manager: pyvisa.ResourceManager | None = None):
        self.interface_resource_name = interface_resource_name
        parsed = rname.parse_resource_name(interface_resource_name)
        if not isinstance(parsed, (rname.PrlgxASRLIntfc, rname.PrlgxTCPIPIntfc)):
            raise ValueError(f"{interface_resource_name!r} is not a Prologix controller's resource name "
                             f"(PRLGX-TCPIP<board>::<host>::<port>::INTFC or PRLGX-ASRL<board>::<device>::INTFC)")
        self.board = int(parsed.board or 0)
        self.timeout_s = float(timeout_s)
        self._manager = resource_manager
        self.generation = 0
        self._interface: Any = None
        self._lock = threading.Lock()
        self._open()

    @classmethod
    def usb(cls, serial_port: str, *, board: int = 0, **options: Any) -> "PrologixAdapter":
        """A GPIB-USB controller on ``serial_port`` (``/dev/ttyUSB0``, ``COM3``)."""
        return cls(interface_resource_name(serial_port=serial_port, board=board), **options)

    @classmethod
    def ethernet(cls, host: str, port: int = ETHERNET_PORT, *, board: int = 0,
                 **options: Any) -> "PrologixAdapter":
        """A GPIB-ETHERNET controller at ``host`` (TCP port 1234)."""
        return cls(interface_resource_name(host=host, port=port, board=board), **options)

    @property
    def manager(self) -> pyvisa.ResourceManager:
        if self._manager is None:
            self._manager = resource_manager("@py")
        return self._manager

    def _open(self) -> None:
        try:
            self._interface = self.manager.open_resource(self.interface_resource_name,
                                                         timeout=self.timeout_s * 1000.0,
                                                         open_timeout=round(self.timeout_s * 1000.0))
        except Exception as error:  # noqa: BLE001 - pyvisa-py raises a bare Exception for a host it cannot resolve
            self._interface = None
            raise ConnectionLost(self.interface_resource_name,
                                 f"cannot open the Prologix controller: {error}") from error
        if "TCPIP" in self.interface_resource_name:
            send_without_delay(self._interface)
        self.generation += 1

    def use_timeout(self, timeout_s: float) -> None:
        """Wait at most ``timeout_s`` for any reply through the controller from now on (and after reopening)."""
        self.timeout_s = float(timeout_s)
        self.wait_for_replies(self.timeout_s)

    def wait_for_replies(self, timeout_s: float) -> None:
        """Set the wait for a reply on the controller's session, for now (:meth:`use_timeout` to keep it)."""
        if self._interface is not None:
            self._interface.timeout = timeout_s * 1000.0

    def close(self) -> None:
        interface, self._interface = self._interface, None
        if interface is not None:
            try:
                interface.close()
            except (VisaIOError, OSError):
                pass

    def reconnect(self, seen_generation: int) -> None:
        """Reopen the controller connection, unless another instrument already did since ``seen_generation``."""
        with self._lock:
            if self.generation != seen_generation and self._interface is not None:
                return
            self.close()
            self._open()

    def instrument(self, primary_address: int, secondary_address: int | None = None, *,
                   name: str | None = None) -> "PrologixInstrument":
        """A transport to the instrument at ``primary_address`` (0 to 30) behind this controller."""
        if not 0 <= primary_address <= 30:
            raise ValueError(f"GPIB primary address must be 0 to 30, got {primary_address}")
        return PrologixInstrument(self, primary_address, secondary_address, name=name)

    def trigger(self, primary_addresses: Sequence[int]) -> None:
        """One Group Execute Trigger to all ``primary_addresses`` (``++trg a b ...``, at most 15)."""
        if not 1 <= len(primary_addresses) <= 15:
            raise ValueError("the Prologix ++trg command takes 1 to 15 addresses")
        command = "++trg " + " ".join(str(int(address)) for address in primary_addresses) + "\n"
        if self._interface is None or peer_closed(self._interface):
            raise ConnectionLost(self.interface_resource_name, "controller connection is closed")
        from pyvisa_py.highlevel import PyVisaLibrary  # loaded: it opened the controller

        visalib = self.manager.visalib
        # only pyvisa-py knows PRLGX resources, so the library that opened the controller is pyvisa-py's
        assert isinstance(visalib, PyVisaLibrary)
        session = visalib.sessions.get(self._interface.session)
        lock = getattr(session, "intfc_lock", None) or threading.Lock()
        try:
            with lock:
                self._interface.write_raw(command.encode("ascii"))
        except (VisaIOError, OSError) as error:
            raise ConnectionLost(self.interface_resource_name, f"cannot send ++trg: {error}") from error


class PrologixInstrument(VisaTransport):
    """A GPIB instrument behind a :class:`PrologixAdapter`; reopening also reconnects the controller."""

    def __init__(self, adapter: PrologixAdapter, primary_address: int, secondary_address: int | None = None,
                 *, name: str | None = None):
        self.adapter = adapter
        self.primary_address = primary_address
        self._generation = adapter.generation
        resource = f"GPIB{adapter.board}::{primary_address}::INSTR"
        if secondary_address is not None:
            resource = f"GPIB{adapter.board}::{primary_address}::{secondary_address}::INSTR"
        super().__init__(resource, name=name or f"{resource} via {adapter.interface_resource_name}",
                         timeout_s=adapter.timeout_s, resource_manager=adapter.manager,
                         read_termination=None)
        # pyvisa-py 0.8.1 discards stale input before a Prologix write by reading until the
        # socket is quiet; on a socket the controller has closed that loop never ends. Looking
        # first turns the closed connection into ConnectionLost instead.
        self.check_peer_before_io = True

    @property
    def timeout_s(self) -> float:
        return self.adapter.timeout_s

    @timeout_s.setter
    def timeout_s(self, value: float) -> None:
        self._timeout_s = float(value)
        self.adapter.use_timeout(value)

    def _wait_for_replies(self, timeout_s: float) -> None:
        self.adapter.wait_for_replies(timeout_s)

    def reopen(self) -> None:
        self.close()
        self.adapter.reconnect(self._generation)
        self._generation = self.adapter.generation
        self._open()
