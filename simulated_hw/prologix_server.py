"""A simulated Prologix GPIB-ETHERNET controller with simulated instruments on its GPIB bus.

It speaks the controller's protocol as its user manual describes it (Prologix
GPIB-ETHERNET Controller User Manual, sections 8 "Data transmission" and 9
"Commands"), so that pyvisa-py's Prologix support — and through it the real
drivers — run against it unchanged:

* a line starting with ``++`` is a controller command; anything else is data
  for the instrument at the current address (``++addr``). Unescaped CR and
  LF end a line; ESC makes the next byte (ESC, CR, LF, ``+``) literal data;
* ``++read eoi`` (or ``++read``) sends what the addressed instrument has to
  say; with nothing to say the controller times out (``++read_tmo_ms``) and
  sends nothing;
* ``++trg`` triggers the addressed instrument; ``++trg 16 17`` sends one
  Group Execute Trigger to the listed addresses;
* ``++auto 1`` reads back after every data line (read-after-write);
* ``++addr``, ``++ver`` answer; ``++clr`` is a selected device clear;
  ``++mode``, ``++eoi``, ``++eos``, ``++eot_enable``, ``++eot_char``,
  ``++read_tmo_ms``, ``++ifc``, ``++savecfg``, ``++loc``, ``++llo`` are
  accepted; anything else is answered ``Unrecognized command``.

All instruments of a group trigger see it at the same clock instant, as on a
real bus where one GET reaches every listener at once.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass, field
from typing import Mapping, Protocol

from drivers.clock import Clock
from simulated_hw.scpi_server import ThreadedTcpServer

ESC, CR, LF = 0x1B, 0x0D, 0x0A
VERSION = "Prologix GPIB-ETHERNET Controller version 01.06.06.00 (simulated)"


class GpibDevice(Protocol):
    clock: Clock

    def handle(self, message: str) -> str | None: ...

    def group_execute_trigger(self, time_s: float | None = None) -> None: ...

    def selected_device_clear(self) -> None: ...


@dataclass
class _ControllerState:
    address: int = 0
    auto: bool = False
    output: dict[int, list[str]] = field(default_factory=dict)


class PrologixServer(ThreadedTcpServer[_ControllerState]):
    """A Prologix GPIB-ETHERNET controller and its bus.

    Parameters
    ----------
    devices : mapping of int to GpibDevice
        Simulated instruments by GPIB primary address.
    host, port : str, int
        Where to listen; port 0 picks a free one (a real controller uses 1234).
    """

    def __init__(self, devices: Mapping[int, GpibDevice], host: str = "127.0.0.1", port: int = 0):
        super().__init__(host, port)
        self.devices = dict(devices)
        self.group_triggers: list[tuple[int, ...]] = []
        #: Every controller command received (``addr 16``, ``read eoi`` ...), for inspection.
        self.controller_commands: list[str] = []

    @property
    def interface_resource_name(self) -> str:
        """The pyvisa-py resource name of this controller."""
        return f"PRLGX-TCPIP0::{self.host}::{self.port}::INTFC"

    def new_connection(self) -> _ControllerState:
        return _ControllerState()

    # -- the byte stream -----------------------------------------------------------------
    def received(self, state: _ControllerState, buffer: bytes, connection: socket.socket) -> bytes:
        line = bytearray()
        escaped_line = False
        index = 0
        while index < len(buffer):
            byte = buffer[index]
            if byte == ESC:
                if index + 1 >= len(buffer):
                    break  # the escaped byte has not arrived yet
                line.append(buffer[index + 1])
                escaped_line = True
                index += 2
                continue
            index += 1
            if byte in (CR, LF):
                if line:
                    self._line(state, bytes(line), escaped_line, connection)
                line.clear()
                escaped_line = False
                buffer = buffer[index:]
                index = 0
                continue
            line.append(byte)
        return buffer

    def _line(self, state: _ControllerState, line: bytes, had_escapes: bool,
              connection: socket.socket) -> None:
        text = line.decode("ascii", "replace")
        if text.startswith("++") and not (had_escapes and line[:2] != b"++"):
            reply = self._controller_command(state, text[2:].strip())
            if reply is not None:
                connection.sendall(reply.encode("ascii") + b"\n")
            return
        device = self.devices.get(state.address)
        if device is None:
            return  # nobody listens at that address: the data goes nowhere
        reply = device.handle(text)
        if reply is not None:
            state.output.setdefault(state.address, []).append(reply)
        if state.auto:
            pending = self._take_output(state)
            if pending is not None:
                connection.sendall(pending.encode("ascii", "replace") + b"\n")

    def _controller_command(self, state: _ControllerState, command: str) -> str | None:
        self.controller_commands.append(command)
        name, _, argument = command.partition(" ")
        name = name.lower()
        argument = argument.strip()
        if name == "addr":
            if not argument:
                return str(state.address)
            state.address = int(argument.split()[0])
            return None
        if name == "auto":
            if not argument:
                return "1" if state.auto else "0"
            state.auto = argument == "1"
            return None
        if name == "read":
            return self._take_output(state)
        if name == "trg":
            addresses = tuple(int(a) for a in argument.split() if 0 <= int(a) <= 30) or (state.address,)
            self.group_triggers.append(addresses)
            listeners = [self.devices[address] for address in addresses if address in self.devices]
            if listeners:
                instant = listeners[0].clock.now()      # one GET: every listener, one instant
                for device in listeners:
                    device.group_execute_trigger(instant)
            return None
        if name == "clr":
            if state.address in self.devices:
                self.devices[state.address].selected_device_clear()
            state.output.pop(state.address, None)
            return None
        if name == "ver":
            return VERSION
        if name in ("mode", "eoi", "eos", "eot_enable", "eot_char", "read_tmo_ms", "ifc", "savecfg",
                    "loc", "llo", "rst", "spoll", "srq", "status", "lon", "help"):
            return None
        return "Unrecognized command"

    @staticmethod
    def _take_output(state: _ControllerState) -> str | None:
        pending = state.output.get(state.address)
        return pending.pop(0) if pending else None
