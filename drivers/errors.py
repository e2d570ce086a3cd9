"""Typed instrument errors: what went wrong, on which instrument, with the reply.

Every error a driver or transport raises is an :class:`InstrumentError`, so
the loop can catch one class, put the heater at 0 W and log ``str(error)``,
which names the instrument, the reason, the offending reply (if any) and the
messages the instrument's error queue held when the fault was examined.

Examples
--------
>>> error = BadReply("flange DMM", "reading is not a number", reply="#@!")
>>> print(error)
flange DMM: reading is not a number (reply '#@!')
>>> error.error_queue = ((-113, "Undefined header"),)
>>> print(error)
flange DMM: reading is not a number (reply '#@!'); error queue: -113,"Undefined header"
>>> isinstance(HeaterLimitRefused("heater", "0.2 A above 0.1 A"), ValueError)
True

A caller that must act before it asks a failing instrument anything (the daemon
switches the heater off first) has the driver leave the error queue for later
(:attr:`drivers.scpi.ScpiInstrument.examines_faults_at_once`) and calls
:meth:`InstrumentError.examine` when it is ready.
"""

from __future__ import annotations

from typing import Callable

#: One error-queue entry: (code, message), e.g. ``(-113, "Undefined header")``.
QueueEntry = tuple[int, str]


class InstrumentError(Exception):
    """Base of every instrument fault.

    Parameters
    ----------
    instrument : str
        Which instrument (driver name and, where known, its address).
    reason : str
        What went wrong, in lab words.
    reply : str, optional
        The instrument's reply that caused the error, verbatim.
    error_queue : tuple of (int, str)
        Messages read from the instrument's error queue after the fault.
    """

    def __init__(self, instrument: str, reason: str, *, reply: str | None = None,
                 error_queue: tuple[QueueEntry, ...] = ()):
        super().__init__(instrument, reason)
        self.instrument = instrument
        self.reason = reason
        self.reply = reply
        self.error_queue = tuple(error_queue)
        self._examine: Callable[["InstrumentError"], None] | None = None

    def __str__(self) -> str:
        text = f"{self.instrument}: {self.reason}"
        if self.reply is not None:
            text += f" (reply {self.reply!r})"
        if self.error_queue:
            text += "; error queue: " + "; ".join(
                f'{code},"{message}"' for code, message in self.error_queue)
        return text

    def examine_later(self, examine: Callable[["InstrumentError"], None]) -> None:
        """Leave reading the failing instrument's error queue to :meth:`examine` (the first one given counts)."""
        if self._examine is None:
            self._examine = examine

    def examine(self) -> None:
        """Attach what the failing instrument's error queue holds, if reading it was left for later (once)."""
        examine, self._examine = self._examine, None
        if examine is not None:
            examine(self)

    def relabelled(self, instrument: str) -> "InstrumentError":
        """The same error naming ``instrument`` (a driver adds its name to a transport's)."""
        self.instrument = instrument
        self.args = (instrument, self.reason)
        return self


class InstrumentTimeout(InstrumentError):
    """No reply (or no new reading) within the allowed time."""


class ConnectionLost(InstrumentError):
    """The connection dropped; the transport's ``reopen()`` may recover it."""


class OverflowReading(InstrumentError):
    """The DMM reported an overflow (+9.9E37): the input is above the range. Never a temperature."""


class BadReply(InstrumentError):
    """A reply that cannot be parsed (garbage, wrong field count, not a number)."""


class InstrumentReportedError(InstrumentError):
    """The instrument's error queue (``:SYSTem:ERRor?``) held messages."""


class IdentityMismatch(InstrumentError):
    """``*IDN?`` at connect named another model than the driver expects."""


class HeaterRefused(InstrumentError):
    """The heater supply did not turn its output on (interlock, output enable, over-temperature)."""


class HeaterOutputOff(HeaterRefused):
    """The supply's output went off by itself while driving the heater (interlock opened, output enable,
    front panel): the loop's power was not reaching the heater."""


class HeaterCompliance(InstrumentError):
    """The heater supply reached its voltage compliance: open heater or too high a resistance."""


class HeaterLimitRefused(InstrumentError, ValueError):
    """A heater request outside its limits (above the maximum current, negative power).

    Nothing was sent to the supply: its output is as it was before the request.
    """
