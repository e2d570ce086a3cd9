"""A transport that calls a simulated instrument directly, without any wire.

Used by ``cryod --simulate --speed max`` (virtual time, as fast as the CPU
allows) and by the tests: the driver's SCPI goes to the emulator's parser
unchanged, replies come back through an output queue, as on a GPIB bus.

Timing follows the injected clock: a reply that never comes costs
``timeout_s`` of that clock before :class:`~drivers.errors.InstrumentTimeout`
is raised (on a :class:`drivers.clock.VirtualClock` that is no real time).
"""

from __future__ import annotations

from collections import deque
from typing import Protocol

from drivers.clock import Clock
from drivers.errors import ConnectionLost, InstrumentTimeout


class SimulatedDevice(Protocol):
    """What an in-process transport needs of a simulated instrument."""

    clock: Clock

    def open_session(self) -> int: ...

    def session_alive(self, session: int) -> bool: ...

    def handle(self, message: str) -> str | None: ...

    def group_execute_trigger(self, time_s: float | None = None) -> None: ...

    def selected_device_clear(self) -> None: ...


class InProcessTransport:
    """A :class:`~drivers.transports.base.Transport` to a simulated instrument in this process.

    Parameters
    ----------
    device : SimulatedDevice
        The simulated instrument (e.g. :class:`simulated_hw.keithley2002.Keithley2002Emulator`).
    name : str
        Description for error messages.
    timeout_s : float
        Longest wait for a reply, on ``clock``.
    clock : Clock, optional
        Clock on which a missing reply costs ``timeout_s``; the device's by default.
    """

    def __init__(self, device: SimulatedDevice, name: str = "in-process", *, timeout_s: float = 1.0,
                 clock: Clock | None = None):
        self.device = device
        self.name = name
        self.timeout_s = float(timeout_s)
        self.clock = clock if clock is not None else device.clock
        self._replies: deque[str] = deque()
        self._session: int | None = device.open_session()

    @property
    def resource(self) -> SimulatedDevice:
        """The device itself (what a simulated GPIB interface addresses)."""
        return self.device

    def _check_connection(self) -> None:
        if self._session is None:
            raise ConnectionLost(self.name, "transport is closed")
        if not self.device.session_alive(self._session):
            self._session = None
            self._replies.clear()
            raise ConnectionLost(self.name, "connection to the instrument dropped")

    def write(self, command: str) -> None:
        self._check_connection()
        reply = self.device.handle(command)
        if reply is not None:
            self._replies.append(reply)

    def read(self) -> str:
        self._check_connection()
        if not self._replies:
            self.clock.sleep_until(self.clock.now() + self.timeout_s)
            raise InstrumentTimeout(self.name, f"no reply within {self.timeout_s:g} s")
        return self._replies.popleft()

    def query(self, command: str) -> str:
        self._check_connection()
        reply = self.device.handle(command)
        if reply is not None and not self._replies:     # the usual case: this reply, the only one waiting
            return reply
        if reply is not None:
            self._replies.append(reply)
        return self.read()

    def trigger(self) -> None:
        self._check_connection()
        self.device.group_execute_trigger()

    def clear(self) -> None:
        """Selected device clear: drop pending replies."""
        self._check_connection()
        self._replies.clear()
        self.device.selected_device_clear()

    def close(self) -> None:
        self._session = None
        self._replies.clear()

    def reopen(self) -> None:
        self.close()
        self._session = self.device.open_session()
