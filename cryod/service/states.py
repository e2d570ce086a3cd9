"""The control loop's states, with what each one means for the heater.

Three of them are the regulator's modes (:class:`cryod.control.regulator.RegulatorMode`):
the loop is in one of them while it runs. The others are the loop's own: waiting
for valid readings (at start-up, after a fault) and stopped.

Examples
--------
>>> LoopState.RECOVERING.waits_for_readings, LoopState.MANUAL.heater_may_be_on
(True, True)
>>> LoopState("closed") is LoopState.CLOSED
True
"""

from __future__ import annotations

from enum import StrEnum


class LoopState(StrEnum):
    """What the loop is doing (the ``state`` column and ``cryod ctl status``).

    Attributes
    ----------
    waits_for_readings : bool
        Heater off until ``safety.valid_readings_to_resume`` valid readings in a row.
    heater_may_be_on : bool
        The heater follows the regulator (closed loop or manual power).
    """

    waits_for_readings: bool
    heater_may_be_on: bool

    def __new__(cls, value: str, waits_for_readings: bool, heater_may_be_on: bool):
        member = str.__new__(cls, value)
        member._value_ = value
        member.waits_for_readings = waits_for_readings
        member.heater_may_be_on = heater_may_be_on
        return member

    HOLDING = ("holding", True, False)          # start-up: heater off until readings are valid and in range
    CLOSED = ("closed", False, True)            # regulating to the setpoint
    MANUAL = ("manual", False, True)            # open loop at a commanded heater power
    OFF = ("off", False, False)                 # heater off on request
    RECOVERING = ("recovering", True, False)    # after a transient fault: heater off, waiting for valid readings
    STOPPED = ("stopped", False, False)
