"""A hardware trigger edge the PC can make: a serial port's modem-control line.

The Keithley 2002 takes a trigger on its rear EXTERNAL TRIGGER input (a
falling TTL edge; User's Manual section 2.7.6) or on a Trigger Link line
("Trigger Link", p. 2-53; asynchronous mode uses the same TTL pulses). Wire both DMMs to the same
edge and they start integrating at the same instant, whatever the bus
latency. A PC makes the edge with a serial port's RTS (or DTR) line,
through a level shifter from RS-232 (±5 to ±12 V) to TTL, or an
open-collector transistor for a Trigger Link line (docs/explanation/instruments.md,
"Trigger cabling").

:class:`SerialControlLine` holds the line at its idle level and pulses it
for ``pulse_width_s``. The 2002 triggers on a falling TTL edge, so the idle
level must come out TTL high: with a non-inverting level shifter (a clamp:
RS-232 positive gives TTL high) the line idles asserted and the pulse
deasserts it (``idle_asserted=True``, the default); with an inverting one
(a MAX232-type receiver) it idles deasserted and the pulse asserts it
(``idle_asserted=False``). It works on anything with a writable
``rts``/``dtr`` attribute: a ``serial.Serial`` for the lab, a simulated
port that fans the edge out to simulated DMMs for ``cryod --simulate`` and
the tests.

Examples
--------
>>> from drivers.clock import VirtualClock
>>> class Port:
...     def __init__(self): self.levels = []
...     rts = property(lambda self: self.levels[-1], lambda self, level: self.levels.append(level))
>>> port, clock = Port(), VirtualClock()
>>> line = SerialControlLine(port, clock, line="rts", pulse_width_s=0.001)
>>> line.pulse(); port.levels, clock.now()
([True, False, True], 0.001)
"""

from __future__ import annotations

from typing import Any, Protocol

from drivers.clock import Clock
from drivers.errors import ConnectionLost


class TriggerOutput(Protocol):
    """Something that makes one trigger edge on demand."""

    def pulse(self) -> None:
        """Make one trigger pulse (its leading edge is the trigger)."""


class SerialControlLine:
    """A trigger pulse on a serial port's RTS or DTR line.

    Parameters
    ----------
    port : serial.Serial or object with ``rts``/``dtr``
        An open port (``serial.Serial("/dev/ttyS0")``); see :meth:`open` to open one by name.
    clock : Clock
        Times the pulse width.
    line : {'rts', 'dtr'}
        Which modem-control line is wired to the trigger inputs.
    pulse_width_s : float
        Width of the pulse (the 2002 needs microseconds; 1 ms is safe through USB adapters).
    idle_asserted : bool
        The line's level between pulses: True (asserted) behind a non-inverting level
        shifter, False behind an inverting one; either way the trigger edge starts the pulse.
    """

    def __init__(self, port: Any, clock: Clock, *, line: str = "rts", pulse_width_s: float = 0.001,
                 idle_asserted: bool = True):
        if line not in ("rts", "dtr"):
            raise ValueError(f"line must be 'rts' or 'dtr', got {line!r}")
        if not pulse_width_s > 0.0:
            raise ValueError(f"pulse width must be positive, got {pulse_width_s}")
        self.port = port
        self.clock = clock
        self.line = line
        self.pulse_width_s = float(pulse_width_s)
        self.idle_level = idle_asserted
        self._set(self.idle_level)

    @classmethod
    def open(cls, device: str, clock: Clock, **options: Any) -> "SerialControlLine":
        """Open ``device`` (``/dev/ttyS0``, ``COM1``) with pyserial and use one of its lines."""
        import serial  # pyserial

        try:
            port = serial.Serial(device)
        except serial.SerialException as error:
            raise ConnectionLost(device, f"cannot open the trigger port: {error}") from error
        return cls(port, clock, **options)

    def _set(self, level: bool) -> None:
        try:
            setattr(self.port, self.line, level)
        except OSError as error:
            raise ConnectionLost(str(getattr(self.port, "port", "trigger port")),
                                 f"cannot drive {self.line.upper()}: {error}") from error

    def pulse(self) -> None:
        self._set(not self.idle_level)
        self.clock.sleep_until(self.clock.now() + self.pulse_width_s)
        self._set(self.idle_level)

    def close(self) -> None:
        close = getattr(self.port, "close", None)
        if close is not None:
            close()
