"""cryod's alarms as EPICS alarm severities and STAT on the PVs they concern, so that an alarm server sees them.

Each of cryod's alarms (docs/how-to/alarms.md, "Alarms") concerns the PVs of what it watches:

========================  ===========================  ========  =========================================
alarm                     PVs                          raised    STAT
========================  ===========================  ========  =========================================
``deviation``             T2, T2_AVG, STABLE           MINOR     HIGH or LOW (T2's average above or below
                                                                 the setpoint); STATE on STABLE
``stability``             T2, STABLE                   MINOR     STATE
``ptc_stage_warm``        T5                           MAJOR     HIGH
``heater_near_top``       HEATER, HEATER_MEAN          MINOR     HIGH
``cooler_line_lost``      LINE, FEEDFORWARD_LOCKED     MAJOR     STATE
========================  ===========================  ========  =========================================

MAJOR is for what needs someone now, whatever the experiment: the cooler's second stage warming
towards the over-temperature limit that stops the daemon, and a cooler that stopped (the cryostat
warms). MINOR is for what spoils the data but leaves the cryostat safe and regulated: T2 away from
the setpoint or too noisy, a setpoint that needs more heater than there is. A latched alarm (its
condition over, not yet acknowledged) is MINOR on the same PVs, whatever it was when raised: the
alarm server shows that it happened, and ``ALARM_ACK`` (or ``cryod ctl alarms ack``) clears it.

Beyond the alarms: every reading is INVALID with STAT COMM while the IOC has no stream from the
daemon, and INVALID with UDF before the daemon's loop runs; STATE is MAJOR while the loop recovers
from a fault or has stopped, MINOR while it holds the heater off waiting for valid readings.

Examples
--------
>>> alarms = [{"name": "ptc_stage_warm", "state": "raised"}, {"name": "deviation", "state": "latched"}]
>>> severities = pv_alarms(alarms, flange_above_setpoint=True)
>>> severities["T5"], severities["T2"]
((2, 4), (1, 4))
"""

from __future__ import annotations

from typing import Iterable, Mapping

# Severities and STAT codes of EPICS base's alarm.h.
NO_ALARM, MINOR, MAJOR, INVALID = 0, 1, 2, 3
STAT_NONE, STAT_WRITE, STAT_HIGH, STAT_LOW, STAT_STATE, STAT_COMM, STAT_UDF = 0, 2, 4, 6, 7, 9, 17

#: Each alarm: the PVs it concerns, its severity when raised, and its STAT on each (None: HIGH or LOW by the
#: side of the setpoint T2's average is on).
ALARM_PVS: dict[str, tuple[int, dict[str, int | None]]] = {
    "deviation": (MINOR, {"T2": None, "T2_AVG": None, "STABLE": STAT_STATE}),
    "stability": (MINOR, {"T2": STAT_STATE, "STABLE": STAT_STATE}),
    "ptc_stage_warm": (MAJOR, {"T5": STAT_HIGH}),
    "heater_near_top": (MINOR, {"HEATER": STAT_HIGH, "HEATER_MEAN": STAT_HIGH}),
    "cooler_line_lost": (MAJOR, {"LINE": STAT_STATE, "FEEDFORWARD_LOCKED": STAT_STATE}),
}
#: The severity of an alarm latched (its condition over, not acknowledged).
LATCHED_SEVERITY = MINOR
#: STATE's severity in each of the loop's states that asks for attention.
STATE_SEVERITY = {"holding": MINOR, "waiting": MINOR, "recovering": MAJOR, "stopped": MAJOR, "lost": INVALID}


def pv_alarms(alarms: Iterable[Mapping], flange_above_setpoint: bool | None) -> dict[str, tuple[int, int]]:
    """(severity, STAT) of each PV some alarm concerns, from the status' alarms (those raised or latched).

    Parameters
    ----------
    alarms : iterable of mapping
        Each with ``name`` and ``state`` (``raised`` or ``latched``), as the daemon's status gives them.
    flange_above_setpoint : bool or None
        Whether T2's 10 s average is above the setpoint (None: unknown; a deviation is then HIGH).

    Returns
    -------
    dict
        PV name to (severity, STAT); the highest severity where two alarms concern one PV. PVs no alarm
        concerns are not in it.
    """
    found: dict[str, tuple[int, int]] = {}
    for alarm in alarms:
        entry = ALARM_PVS.get(str(alarm.get("name")))
        if entry is None:
            continue
        raised_severity, stats = entry
        severity = raised_severity if alarm.get("state") == "raised" else LATCHED_SEVERITY
        for pv, stat in stats.items():
            if stat is None:
                stat = STAT_LOW if flange_above_setpoint is False else STAT_HIGH
            if severity > found.get(pv, (NO_ALARM, STAT_NONE))[0]:
                found[pv] = (severity, stat)
    return found


__all__ = ["pv_alarms", "ALARM_PVS", "STATE_SEVERITY", "NO_ALARM", "MINOR", "MAJOR", "INVALID",
           "STAT_NONE", "STAT_WRITE", "STAT_HIGH", "STAT_LOW", "STAT_STATE", "STAT_COMM", "STAT_UDF"]
