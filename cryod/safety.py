"""Faults, what each one means for the heater, and the checks on every reading.

Every fault puts the heater at 0 W in the tick that finds it and is recorded
with its cause. Then the daemon either recovers (transient faults: reconnect,
and resume only after fresh valid readings) or exits with the fault's exit
code so that systemd restarts it.

| cause                      | recovers? | exit code when not |
|----------------------------|-----------|--------------------|
| instrument_timeout         | yes       | 4 (recovery timed out) |
| connection_lost            | yes       | 4                  |
| bad_reply                  | yes       | 4                  |
| instrument_error           | yes       | 4                  |
| sensor_overflow            | yes       | 4                  |
| sensor_out_of_calibration  | yes       | 4                  |
| sensor_stale               | yes       | 4                  |
| over_temperature           | no        | 3                  |
| heater_fault               | no        | 6                  |
| overrun_streak             | no        | 5                  |
| exception                  | no        | 1                  |
| stop_requested (SIGTERM)   | no        | 0                  |
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.errors import (
    BadReply, ConnectionLost, HeaterCompliance, HeaterLimitRefused, HeaterRefused, IdentityMismatch,
    InstrumentError, InstrumentReportedError, InstrumentTimeout, OverflowReading,
)

EXIT_OK = 0
EXIT_EXCEPTION = 1
EXIT_CONFIG = 2
EXIT_OVER_TEMPERATURE = 3
EXIT_INSTRUMENTS_LOST = 4
EXIT_OVERRUN_STREAK = 5
EXIT_HEATER_FAULT = 6

RECOVERABLE = {
    "instrument_timeout", "connection_lost", "bad_reply", "instrument_error",
    "sensor_overflow", "sensor_out_of_calibration", "sensor_stale",
}
EXIT_CODES = {
    "over_temperature": EXIT_OVER_TEMPERATURE,
    "heater_fault": EXIT_HEATER_FAULT,
    "overrun_streak": EXIT_OVERRUN_STREAK,
    "exception": EXIT_EXCEPTION,
    "stop_requested": EXIT_OK,
    "identity_mismatch": EXIT_CONFIG,
}


@dataclass(frozen=True)
class Fault:
    """A reason to put the heater at 0 W.

    Attributes
    ----------
    cause : str
        One of the causes in the module table.
    message : str
        What happened, for the log, the status and the record.
    """

    cause: str
    message: str

    @property
    def recoverable(self) -> bool:
        return self.cause in RECOVERABLE

    @property
    def exit_code(self) -> int:
        return EXIT_CODES.get(self.cause, EXIT_INSTRUMENTS_LOST)

    def __str__(self) -> str:
        return f"{self.cause}: {self.message}"


def fault_from_instrument_error(error: InstrumentError) -> Fault:
    """Classify a driver error."""
    if isinstance(error, (HeaterRefused, HeaterCompliance, HeaterLimitRefused)):
        cause = "heater_fault"
    elif isinstance(error, OverflowReading):
        cause = "sensor_overflow"
    elif isinstance(error, InstrumentTimeout):
        cause = "instrument_timeout"
    elif isinstance(error, ConnectionLost):
        cause = "connection_lost"
    elif isinstance(error, BadReply):
        cause = "bad_reply"
    elif isinstance(error, IdentityMismatch):
        cause = "identity_mismatch"
    elif isinstance(error, InstrumentReportedError):
        cause = "instrument_error"
    else:
        cause = "instrument_error"
    return Fault(cause, str(error))


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
                return Fault("sensor_stale", f"{name} DMM returned {value!r} ohm {self._repeats[index]} times "
                                             f"in a row: no new readings")
        self._last = (flange_ohm, ptc_stage_ohm)
        return None

    def check_temperatures(self, flange_K: float, ptc_stage_K: float) -> Fault | None:
        """A fault when a temperature is above its limit."""
        if flange_K > self.flange_max_K:
            return Fault("over_temperature", f"T2 {flange_K:.4f} K above the limit {self.flange_max_K:g} K")
        if ptc_stage_K > self.ptc_stage_max_K:
            return Fault("over_temperature", f"T5 {ptc_stage_K:.4f} K above the limit {self.ptc_stage_max_K:g} K")
        return None

    def reset(self) -> None:
        """Forget history (after a reconnect)."""
        self._last = (None, None)
        self._repeats = [0, 0]
