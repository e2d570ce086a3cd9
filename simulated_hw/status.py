"""The IEEE 488.2 and SCPI status model every simulated instrument shares.

As the Keithley manuals draw it (Model 2002 User's Manual, section 3.8
"Status structure"; 2400 Series SourceMeter User's Manual, section 15,
Figure 15-1; Model 6220/6221 Reference Manual, section 11):

* the **standard event status register** (``*ESR?`` reads and clears it,
  ``*ESE`` enables its bits into the status byte): B0 operation complete
  (``*OPC``), B2 query error, B3 device-dependent error, B4 execution error,
  B5 command error, B7 power on. An error entering the error queue sets the
  bit of its class (SCPI 1999, "Error/event numbers"): -100 to -199 command
  error, -200 to -299 execution error, -300 to -399 and every positive
  (instrument-specific) number device-dependent error, -400 to -499 query
  error.
* the **status byte** (``*STB?``, not cleared by reading): B0 MSB
  measurement summary, B2 EAV error available, B3 QSB questionable summary,
  B4 MAV message available, B5 ESB event summary, B6 MSS master summary
  (any bit both set and enabled by ``*SRE``), B7 OSB operation summary.
* three **SCPI register sets**, operation, questionable and measurement:
  a condition register the instrument drives, an event register that
  latches the condition's rising edges until read (``:STATus:...[:EVENt]?``
  reads and clears) and an enable register (``:STATus:...:ENABle``) that
  selects the event bits summarised in the status byte.

``*CLS`` clears the event registers, the standard event register and the
error queue; ``:STATus:PRESet`` clears the SCPI enable registers; ``*RST``
changes none of them (IEEE 488.2, 10.32).

Examples
--------
>>> status = StatusModel()
>>> status.read_event_status() == POWER_ON       # first read after power-on
True
>>> status.errors.push(-113, "Undefined header")
>>> status.status_byte() & ERROR_AVAILABLE != 0, status.read_event_status() == COMMAND_ERROR
(True, True)
>>> status.read_event_status()                   # reading cleared it
0
"""

from __future__ import annotations

from typing import Callable

from simulated_hw.scpi import QUEUE_OVERFLOW, ErrorQueue

# standard event status register bits (IEEE 488.2, 11.5.1)
OPERATION_COMPLETE = 1 << 0
QUERY_ERROR = 1 << 2
DEVICE_DEPENDENT_ERROR = 1 << 3
EXECUTION_ERROR = 1 << 4
COMMAND_ERROR = 1 << 5
USER_REQUEST = 1 << 6
POWER_ON = 1 << 7
#: Bits the standard event register can hold (B1, request control, is always 0 here).
STANDARD_EVENT_BITS = 0xFD

# status byte bits, as the Keithley manuals lay them out
MEASUREMENT_SUMMARY = 1 << 0
ERROR_AVAILABLE = 1 << 2
QUESTIONABLE_SUMMARY = 1 << 3
MESSAGE_AVAILABLE = 1 << 4
EVENT_SUMMARY = 1 << 5
MASTER_SUMMARY = 1 << 6
OPERATION_SUMMARY = 1 << 7

#: SCPI registers are 16 bits wide and bit 15 is always 0 (SCPI 1999, 9.1).
REGISTER_MASK = 0x7FFF


def event_bit_of(code: int) -> int:
    """The standard-event bit an error with SCPI number ``code`` sets (0 for none)."""
    if -199 <= code <= -100:
        return COMMAND_ERROR
    if -299 <= code <= -200:
        return EXECUTION_ERROR
    if -399 <= code <= -300 or code > 0:
        return DEVICE_DEPENDENT_ERROR
    if -499 <= code <= -400:
        return QUERY_ERROR
    return 0


class StatusErrorQueue(ErrorQueue):
    """The error queue; each error queued also sets its bit in the standard event register."""

    def __init__(self, status: "StatusModel"):
        super().__init__()
        self._status = status

    def push(self, code: int, message: str) -> None:
        bits = event_bit_of(code)
        if len(self) >= self.capacity:          # the entry becomes -350, a device-dependent error
            bits |= event_bit_of(QUEUE_OVERFLOW[0])
        super().push(code, message)
        self._status.event_status |= bits


class RegisterSet:
    """One SCPI status register set: condition, latched event, enable.

    Parameters
    ----------
    condition : callable returning int, or None
        The condition register as the instrument's state makes it now; None for
        one that the instrument never sets (always 0: nothing to sample).

    The event register latches the bits that went from 0 to 1 in the
    condition (positive transitions, the SCPI default); the instrument's
    condition is sampled on every program message and on every read.
    """

    def __init__(self, condition: Callable[[], int] | None = None):
        self._condition = condition
        self._last_condition = 0
        self.event = 0
        self.enable = 0

    @property
    def is_constant(self) -> bool:
        """The condition is always 0: sampling it can latch nothing."""
        return self._condition is None

    @property
    def condition(self) -> int:
        return 0 if self._condition is None else self._condition() & REGISTER_MASK

    def sample(self) -> None:
        """Latch the condition's rising edges into the event register."""
        if self._condition is None:
            return
        condition = self._condition() & REGISTER_MASK
        self.event |= condition & ~self._last_condition
        self._last_condition = condition

    def read_event(self) -> int:
        """The event register; reading clears it."""
        self.sample()
        value, self.event = self.event, 0
        return value

    @property
    def summary(self) -> bool:
        """Whether an enabled event bit is set (this set's bit in the status byte)."""
        self.sample()
        return bool(self.event & self.enable)


class StatusModel:
    """Standard event register, status byte, SRE, ESE, the error queue and the SCPI register sets.

    Parameters
    ----------
    operation, questionable, measurement : callable returning int, optional
        The condition registers of the three SCPI register sets (None, the default: always 0).
    """

    def __init__(self, *, operation: Callable[[], int] | None = None,
                 questionable: Callable[[], int] | None = None,
                 measurement: Callable[[], int] | None = None):
        self.errors = StatusErrorQueue(self)
        self.event_status = POWER_ON       # the instrument has just been switched on
        self.event_status_enable = 0
        self.service_request_enable = 0
        self.registers = {"OPERATION": RegisterSet(operation), "QUESTIONABLE": RegisterSet(questionable),
                          "MEASUREMENT": RegisterSet(measurement)}
        #: The register sets whose condition can change (the others are always 0: sampling them latches nothing).
        self.changing_registers = tuple(register for register in self.registers.values() if not register.is_constant)

    def sample(self) -> None:
        """Latch condition changes (called on every program message)."""
        for register in self.changing_registers:
            register.sample()

    def read_event_status(self) -> int:
        """``*ESR?``: the standard event register; reading clears it."""
        value, self.event_status = self.event_status & STANDARD_EVENT_BITS, 0
        return value

    def operation_complete(self) -> None:
        """``*OPC``: every operation this emulation has is complete when its command returns."""
        self.event_status |= OPERATION_COMPLETE

    def status_byte(self, message_available: bool = False) -> int:
        """``*STB?``: the status byte with MSS in bit 6 (reading changes nothing)."""
        byte = 0
        if self.registers["MEASUREMENT"].summary:
            byte |= MEASUREMENT_SUMMARY
        if len(self.errors):
            byte |= ERROR_AVAILABLE
        if self.registers["QUESTIONABLE"].summary:
            byte |= QUESTIONABLE_SUMMARY
        if message_available:
            byte |= MESSAGE_AVAILABLE
        if self.event_status & self.event_status_enable:
            byte |= EVENT_SUMMARY
        if self.registers["OPERATION"].summary:
            byte |= OPERATION_SUMMARY
        if byte & self.service_request_enable & ~MASTER_SUMMARY:
            byte |= MASTER_SUMMARY
        return byte

    def clear(self) -> None:
        """``*CLS``: event registers, standard event register and error queue cleared."""
        self.sample()
        for register in self.registers.values():
            register.event = 0
        self.event_status = 0
        self.errors.clear()

    def preset(self) -> None:
        """``:STATus:PRESet``: the SCPI enable registers back to 0 (ESE and SRE are kept)."""
        for register in self.registers.values():
            register.enable = 0


__all__ = ["StatusModel", "RegisterSet", "StatusErrorQueue", "event_bit_of", "OPERATION_COMPLETE",
           "QUERY_ERROR", "DEVICE_DEPENDENT_ERROR", "EXECUTION_ERROR", "COMMAND_ERROR", "POWER_ON",
           "MEASUREMENT_SUMMARY", "ERROR_AVAILABLE", "QUESTIONABLE_SUMMARY", "MESSAGE_AVAILABLE",
           "EVENT_SUMMARY", "MASTER_SUMMARY", "OPERATION_SUMMARY", "REGISTER_MASK"]
