"""Simulated trigger wiring: a shared trigger wire, a serial port driving it, a GPIB board.

These let the drivers' trigger strategies run unchanged against simulated DMMs:

* :class:`SimulatedTriggerLine` — one wire to several DMMs' EXTERNAL TRIGGER
  inputs (a BNC tee) or one Trigger Link line; a pulse reaches all of them at
  the same clock instant;
* :class:`SimulatedSerialPort` — a serial port whose RTS/DTR line, through
  a level shifter, drives a :class:`SimulatedTriggerLine`: the falling edge
  triggers, as with :class:`drivers.trigger_lines.SerialControlLine` in the lab;
* :class:`SimulatedGpibInterface` — a GPIB board with PyVISA's
  ``group_execute_trigger(*resources)``: one GET to several simulated instruments.
"""

from __future__ import annotations

from typing import Protocol, Sequence

from drivers.clock import Clock


class TriggerableDmm(Protocol):
    clock: Clock

    def external_trigger(self, time_s: float | None = None) -> None: ...

    def trigger_link_pulse(self, line: int, time_s: float | None = None) -> None: ...


class SimulatedTriggerLine:
    """A trigger wire to several simulated DMMs.

    Parameters
    ----------
    dmms : sequence of TriggerableDmm
        The DMMs on the wire.
    kind : {'external', 'trigger_link'}
        Rear EXTERNAL TRIGGER inputs, or a Trigger Link line.
    link_line : int
        The Trigger Link line (1 to 6) for ``kind='trigger_link'``.
    """

    def __init__(self, dmms: Sequence[TriggerableDmm], *, kind: str = "external", link_line: int = 1):
        if kind not in ("external", "trigger_link"):
            raise ValueError(f"kind must be 'external' or 'trigger_link', got {kind!r}")
        self.dmms = list(dmms)
        self.kind = kind
        self.link_line = link_line
        self.pulses = 0

    def pulse(self) -> None:
        """One trigger pulse to every DMM on the wire, all at the same instant."""
        self.pulses += 1
        if not self.dmms:
            return
        instant = self.dmms[0].clock.now()
        for dmm in self.dmms:
            if self.kind == "external":
                dmm.external_trigger(instant)
            else:
                dmm.trigger_link_pulse(self.link_line, instant)


class SimulatedSerialPort:
    """A serial port whose modem-control line drives a trigger wire through a non-inverting shifter.

    Deasserting the wired line makes the falling TTL edge that triggers the DMMs.

    Parameters
    ----------
    line : SimulatedTriggerLine
        The wire the level shifter drives.
    wired : {'rts', 'dtr'}
        Which modem-control line is wired.
    """

    def __init__(self, line: SimulatedTriggerLine, *, wired: str = "rts"):
        self.line = line
        self.wired = wired
        self._levels = {"rts": False, "dtr": False}

    def _set(self, name: str, level: bool) -> None:
        falling = self._levels[name] and not level
        self._levels[name] = bool(level)
        if falling and name == self.wired:
            self.line.pulse()

    rts = property(lambda self: self._levels["rts"], lambda self, level: self._set("rts", level))
    dtr = property(lambda self: self._levels["dtr"], lambda self, level: self._set("dtr", level))

    def close(self) -> None:
        pass


class GpibListener(Protocol):
    clock: Clock

    def group_execute_trigger(self, time_s: float | None = None) -> None: ...


class SimulatedGpibInterface:
    """A GPIB board that sends one GET to several simulated instruments (PyVISA's method name)."""

    def __init__(self) -> None:
        self.group_triggers = 0

    def group_execute_trigger(self, *devices: GpibListener) -> None:
        """One GET: every listed device sees the same instant."""
        self.group_triggers += 1
        if not devices:
            return
        instant = devices[0].clock.now()
        for device in devices:
            device.group_execute_trigger(instant)
