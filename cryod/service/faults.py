"""Faults, what each one means for the heater, and the checks on every reading.

Every fault puts the heater at 0 W in the tick that finds it and is recorded
with its cause. Then the daemon either recovers (transient faults: reconnect
where that can help, and resume only after fresh valid readings) or exits
with the fault's exit code so that systemd restarts it.

The causes and their properties are one table, :class:`FaultCause`; a fault
with any other cause cannot be made.

| cause                      | recovers? | reconnects? | exit code when not |
|----------------------------|-----------|-------------|--------------------|
| instrument_timeout         | yes       | yes         | 4 (recovery timed out) |
| connection_lost            | yes       | yes         | 4                  |
| bad_reply                  | yes       | yes         | 4                  |
| instrument_error           | yes       | no          | 4                  |
| sensor_overflow            | yes       | no          | 4                  |
| sensor_out_of_calibration  | yes       | no          | 4                  |
| sensor_stale               | yes       | no          | 4                  |
| readings_too_old           | yes       | no          | 5                  |
| identity_mismatch          | no        |             | 2                  |
| over_temperature           | no        |             | 3                  |
| heater_fault               | no        |             | 6                  |
| heater_output_off          | no        |             | 6                  |
| data_log_failed            | no        |             | 7                  |
| exception                  | no        |             | 1                  |
| stop_requested (SIGTERM)   | no        |             | 0                  |
| signal (SIGABRT, SIGUSR1, ...) | no    |             | 128 + its number   |

Examples
--------
>>> fault = Fault(FaultCause.SENSOR_STALE, "flange DMM repeats itself")
>>> fault.recoverable, int(fault.exit_code), str(fault)
(True, 4, 'sensor_stale: flange DMM repeats itself')
>>> Fault("no_such_cause", "?")
Traceback (most recent call last):
...
ValueError: 'no_such_cause' is not a valid FaultCause
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, StrEnum

from cryod.service.heater_guard import HeaterSwitchedOff
from drivers.errors import (
    BadReply, ConnectionLost, HeaterCompliance, HeaterLimitRefused, HeaterOutputOff, HeaterRefused, IdentityMismatch,
    InstrumentError, InstrumentReportedError, InstrumentTimeout, OverflowReading,
)


class ExitCode(IntEnum):
    """The daemon's exit codes (docs/reference/exit-codes.md)."""

    OK = 0
    EXCEPTION = 1
    CONFIG = 2
    OVER_TEMPERATURE = 3
    INSTRUMENTS_LOST = 4
    #: the loop's readings were too old to set the heater from, again and again (safety.max_reading_age_s)
    READINGS_TOO_OLD = 5
    HEATER_FAULT = 6
    DATA_LOG_FAILED = 7


class FaultCause(StrEnum):
    """Why the heater was put at 0 W, with what follows from it.

    Attributes
    ----------
    recoverable : bool
        The loop waits for valid readings and resumes; otherwise it stops.
    exit_code : ExitCode
        Exit code when the fault ends the run (a recoverable one: when it
        is not cleared within ``safety.recovery_timeout_s``).
    reconnect : bool
        Reopening the instruments' connections may clear it.
    """

    def __new__(cls, value: str, recoverable: bool, exit_code: ExitCode, reconnect: bool = False):
        member = str.__new__(cls, value)
        member._value_ = value
        member.recoverable = recoverable
        member.exit_code = exit_code
        member.reconnect = reconnect
        return member

    INSTRUMENT_TIMEOUT = ("instrument_timeout", True, ExitCode.INSTRUMENTS_LOST, True)
    CONNECTION_LOST = ("connection_lost", True, ExitCode.INSTRUMENTS_LOST, True)
    BAD_REPLY = ("bad_reply", True, ExitCode.INSTRUMENTS_LOST, True)
    INSTRUMENT_ERROR = ("instrument_error", True, ExitCode.INSTRUMENTS_LOST)
    SENSOR_OVERFLOW = ("sensor_overflow", True, ExitCode.INSTRUMENTS_LOST)
    SENSOR_OUT_OF_CALIBRATION = ("sensor_out_of_calibration", True, ExitCode.INSTRUMENTS_LOST)
    SENSOR_STALE = ("sensor_stale", True, ExitCode.INSTRUMENTS_LOST)
    #: The heater would have been set from readings older than ``safety.max_reading_age_s``, or its setting
    #: outlived that bound because the loop did not run (switched off from the watchdog's thread).
    READINGS_TOO_OLD = ("readings_too_old", True, ExitCode.READINGS_TOO_OLD)
    IDENTITY_MISMATCH = ("identity_mismatch", False, ExitCode.CONFIG)
    OVER_TEMPERATURE = ("over_temperature", False, ExitCode.OVER_TEMPERATURE)
    HEATER_FAULT = ("heater_fault", False, ExitCode.HEATER_FAULT)
    HEATER_OUTPUT_OFF = ("heater_output_off", False, ExitCode.HEATER_FAULT)
    DATA_LOG_FAILED = ("data_log_failed", False, ExitCode.DATA_LOG_FAILED)
    EXCEPTION = ("exception", False, ExitCode.EXCEPTION)
    STOP_REQUESTED = ("stop_requested", False, ExitCode.OK)
    #: Another signal that ends the process (cryod.service.stop_signals); the process's exit code is
    #: 128 + its number (the shell's), the daemon's nominal one a failure.
    SIGNAL = ("signal", False, ExitCode.EXCEPTION)


@dataclass(frozen=True)
class Fault:
    """A reason to put the heater at 0 W.

    Attributes
    ----------
    cause : FaultCause
        Given as the enum or its name; any other text is refused.
    message : str
        What happened, for the log, the status and the record.
    """

    cause: FaultCause
    message: str

    def __post_init__(self):
        object.__setattr__(self, "cause", FaultCause(self.cause))

    @property
    def recoverable(self) -> bool:
        return self.cause.recoverable

    @property
    def exit_code(self) -> ExitCode:
        return self.cause.exit_code

    def __str__(self) -> str:
        return f"{self.cause}: {self.message}"


#: Driver errors and the cause each one is, most specific first.
_DRIVER_ERROR_CAUSES = (
    (HeaterSwitchedOff, FaultCause.READINGS_TOO_OLD),
    (HeaterOutputOff, FaultCause.HEATER_OUTPUT_OFF),
    ((HeaterRefused, HeaterCompliance, HeaterLimitRefused), FaultCause.HEATER_FAULT),
    (OverflowReading, FaultCause.SENSOR_OVERFLOW),
    (InstrumentTimeout, FaultCause.INSTRUMENT_TIMEOUT),
    (ConnectionLost, FaultCause.CONNECTION_LOST),
    (BadReply, FaultCause.BAD_REPLY),
    (IdentityMismatch, FaultCause.IDENTITY_MISMATCH),
    (InstrumentReportedError, FaultCause.INSTRUMENT_ERROR),
)


def fault_from_instrument_error(error: InstrumentError) -> Fault:
    """Classify a driver error (an error of no known kind is an ``instrument_error``)."""
    for kinds, cause in _DRIVER_ERROR_CAUSES:
        if isinstance(error, kinds):
            return Fault(cause, str(error))
    return Fault(FaultCause.INSTRUMENT_ERROR, str(error))


class ReadingChecks:
    """Per-reading checks: over-temperature and repeated (stale) readings.

    Parameters
    ----------
    flange_max_K, ptc_stage_max_K : float
        Over-temperature limits.
    max_repeated_readings : int
        This many identical resistance readings in a row mean the DMM is not
        delivering new readings.
    """

    def __init__(self, flange_max_K: float, ptc_stage_max_K: float, max_repeated_readings: int):
        self.flange_max_K = flange_max_K
        self.ptc_stage_max_K = ptc_stage_max_K
        self.max_repeated_readings = max_repeated_readings
        self._last = (None, None)
        self._repeats = [0, 0]

    def check_resistances(self, flange_ohm: float, ptc_stage_ohm: float) -> Fault | None:
        """A fault when either DMM has repeated the same value too often."""
        for index, (name, value) in enumerate((("flange", flange_ohm), ("ptc_stage", ptc_stage_ohm))):
            if value == self._last[index]:
                self._repeats[index] += 1
            else:
                self._repeats[index] = 1
            if self._repeats[index] >= self.max_repeated_readings:
                self._last = (flange_ohm, ptc_stage_ohm)
                return Fault(FaultCause.SENSOR_STALE, f"{name} DMM returned {value!r} ohm {self._repeats[index]} times "
                                             f"in a row: no new readings")
        self._last = (flange_ohm, ptc_stage_ohm)
        return None

    def check_temperatures(self, flange_K: float, ptc_stage_K: float) -> Fault | None:
        """A fault when a temperature is above its limit."""
        if flange_K > self.flange_max_K:
            return Fault(FaultCause.OVER_TEMPERATURE, f"T2 {flange_K:.4f} K above the limit {self.flange_max_K:g} K")
        if ptc_stage_K > self.ptc_stage_max_K:
            return Fault(FaultCause.OVER_TEMPERATURE, f"T5 {ptc_stage_K:.4f} K above the limit {self.ptc_stage_max_K:g} K")
        return None

    def reset(self) -> None:
        """Forget history (after a reconnect)."""
        self._last = (None, None)
        self._repeats = [0, 0]
