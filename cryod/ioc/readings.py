"""Each reading PV's value, from the daemon's rows and status as the stream gives them.

:func:`row_values` gives the PVs updated at every row (:attr:`~cryod.ioc.pv_table.PV.per_row`), each
stamped with the row's sample instant; :func:`status_values` the others, from the status the
:class:`~cryod.interfaces.mirror.DaemonMirror` rebuilds (with the figures of the recent rows) and where
:class:`~cryod.service.settling.SettlingWatch` puts the flange. Numbers the daemon does not have are
NaN (an ``ai`` then shows UDF), texts empty.

Examples
--------
>>> from cryod.records.columns import Row
>>> row = Row(time_s=12.08, lateness_ms=0.2, state="closed", T2_K=5.00001, T5_K=3.4, heater_W=0.11,
...           setpoint_K=5.0, control={"pi_proportional_W": 0.1, "pi_integral_W": 0.02, "ff_W": -0.01})
>>> values = row_values(row)
>>> values["T2"], round(values["HEATER_PI"], 3), values["HEATER_FF"]
(5.00001, 0.12, -0.01)
"""

from __future__ import annotations

import math

from cryod.ioc.pv_table import PVS, STATES
from cryod.records.columns import Row
from cryod.service.daemon_status import DaemonStatus
from cryod.service.settling import AT_TARGET_K, Settling

#: LINE_LIMIT_FROM's choices by the feedforward's ``ff_limit_from`` column.
LIMIT_SOURCES = dict(zip(PVS["LINE_LIMIT_FROM"].choices, range(3)))


def _number(value) -> float:
    """A number, or NaN for None and what is not one."""
    try:
        return math.nan if value is None else float(value)
    except (TypeError, ValueError):
        return math.nan


def row_values(row: Row) -> dict[str, float]:
    """The per-row readings of one row of the loop."""
    control = row.control
    pi = _number(control.get("pi_proportional_W")) + _number(control.get("pi_integral_W"))
    return {"T2": row.T2_K, "T5": row.T5_K, "HEATER": row.heater_W, "HEATER_PI": pi,
            "HEATER_FF": _number(control.get("ff_W")), "SETPOINT_IN_USE": row.setpoint_K,
            "LATENESS": row.lateness_ms}


def alarm_text(alarms) -> str:
    """ALARMS: each alarm raised or latched, with its state and its figure now."""
    return "; ".join(f"{alarm.get('name')} {alarm.get('state')}: {alarm.get('message') or ''}".rstrip(": ")
                     for alarm in alarms)


def status_values(status: DaemonStatus, settling: Settling, connected: bool) -> dict[str, object]:
    """The readings updated at each line of the stream (numbers, choice indices, texts)."""
    loop, recent, timing = status.loop, status.recent, status.loop.timing
    state = "lost" if not connected else ("waiting" if status.waiting_for is not None else loop.state)
    target = loop.target_K if loop.target_K is not None else loop.last_target_K
    ramping = (loop.setpoint_K is not None and loop.target_K is not None
               and abs(loop.setpoint_K - loop.target_K) > AT_TARGET_K)
    source = loop.control.get("ff_limit_from")
    return {
        "T2_AVG": recent.flange_average_K if recent is not None else math.nan,
        "HEATER_MEAN": recent.heater_mean_W if recent is not None else math.nan,
        "LINE": recent.line_amplitude_K if recent is not None else math.nan,
        "LINE_LIMIT": _number(loop.control.get("ff_limit_K")),
        "LINE_LIMIT_FROM": LIMIT_SOURCES.get(source if isinstance(source, str) else "none", 0),
        "FEEDFORWARD_LOCKED": int(_number(loop.control.get("ff_locked")) == 1.0),
        "FEEDFORWARD_SCALE": _number(loop.control.get("ff_scale")),
        "SETPOINT_RBV": _number(target),
        "RAMPING": int(ramping),
        "RAMP_RBV": _number(loop.ramp_K_per_min),
        "STATE": STATES.index(state) if state in STATES else STATES.index("waiting"),
        "STABLE": int(settling.stable),
        "STABLE_FOR": settling.settled_for_s,
        "ZONE": int(loop.zone or 0),
        "LAST_FAULT": loop.last_fault or "",
        "SETPOINT_WARNING": status.setpoint_warning or "",
        "ALARMS": alarm_text(status.alarms),
        "RECORD_PATH": status.record_path or "",
        "LATENESS_P99": timing.lateness_ms_p99,
        "LATENESS_MAX": timing.lateness_ms_max,
        "TICKS": int(timing.ticks),
        "OVERRUNS": int(timing.overruns),
        "CONNECTED": int(connected),
    }


__all__ = ["row_values", "status_values", "alarm_text"]
