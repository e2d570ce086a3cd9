"""Every PV of cryod's IOC: its name after ``ioc.prefix``, record type, unit, precision and meaning.

One table, read by the records (:mod:`cryod.ioc.records`), the docs' PV table (docs/reference/epics-pvs.md,
"EPICS and Bluesky", checked against it by the tests), the Phoebus screen and the archiver's list in
``contrib/epics``. The names ``T2``, ``T5``, ``HEATER``, ``SETPOINT``, ``SETPOINT_RBV``, ``STATE``,
``LINE``, ``LINE_LIMIT``, ``HEATER_OFF`` and ``STABLE`` are a contract: checks outside cryod rely
on them.

Examples
--------
>>> PVS["T2"].record, PVS["T2"].unit
('ai', 'K')
>>> [pv.name for pv in SETTINGS]
['SETPOINT', 'RAMP', 'FEEDFORWARD', 'HEATER_OFF', 'NOTE', 'ALARM_ACK']
"""

from __future__ import annotations

from dataclasses import dataclass

#: The loop's states as STATE's choices, in order (``waiting``: the daemon has not started its loop yet;
#: ``lost``: the IOC has no stream from the daemon).
STATES = ("waiting", "holding", "closed", "closed-limited", "manual", "off", "recovering", "stopped", "lost")
#: The longest name after the prefix (``ioc.prefix`` takes the rest of EPICS' 60 characters).
LONGEST_NAME = 20


@dataclass(frozen=True)
class PV:
    """One PV.

    Attributes
    ----------
    name : str
        After ``ioc.prefix``.
    record : str
        The EPICS record type: ``ai``, ``bi``, ``mbbi``, ``longin``, ``waveform`` (a long string, CHAR),
        ``ao``, ``bo``.
    unit : str
        EGU ("" for none).
    precision : int or None
        PREC of a floating-point record.
    meaning : str
        What it is, for the docs' table.
    choices : tuple of str
        The labels of a ``bi``/``bo`` (0, 1) or an ``mbbi``.
    per_row : bool
        Updated at each row of the loop, stamped with its sample instant (else at each line of the
        daemon's stream, stamped with the latest row's).
    writable : bool
        A setting: a put is a command to the daemon.
    """

    name: str
    record: str
    unit: str
    precision: int | None
    meaning: str
    choices: tuple[str, ...] = ()
    per_row: bool = False
    writable: bool = False


READINGS = (
    PV("T2", "ai", "K", 6, "flange temperature (the control thermometer)", per_row=True),
    PV("T5", "ai", "K", 5, "the cooler's second stage", per_row=True),
    PV("T2_AVG", "ai", "K", 6, "T2 averaged over the last 10 s (17 cooler periods)"),
    PV("HEATER", "ai", "W", 6, "heater power set at this row (PI's part plus the feedforward's)", per_row=True),
    PV("HEATER_PI", "ai", "W", 6, "PI's part of HEATER (proportional plus integral)", per_row=True),
    PV("HEATER_FF", "ai", "W", 6, "the feedforward waveform's part of HEATER (negative half of each cooler cycle)",
       per_row=True),
    PV("HEATER_MEAN", "ai", "W", 6, "the heater's level: its power over the last whole cooler cycles"),
    PV("HEATER_MAX", "ai", "W", 4, "the heater's largest power, R I_max^2"),
    PV("LINE", "ai", "K", 7, "the cooler line on T2: harmonics 1-6 of the cooler's frequency together "
                             "(sqrt(2) x rms of T2's periodic part)"),
    PV("LINE_LIMIT", "ai", "K", 7, "the least line any heater waveform can leave at this setpoint (the "
                                   "feedforward's physical limit)"),
    PV("LINE_LIMIT_FROM", "mbbi", "", None, "what LINE_LIMIT was computed from: the controller's model or the "
                                            "plant the feedforward learned", choices=("none", "model", "learned")),
    PV("FEEDFORWARD_LOCKED", "bi", "", None, "the feedforward's phase tracker is locked to the cooler",
       choices=("Unlocked", "Locked")),
    PV("FEEDFORWARD_SCALE", "ai", "", 3, "the feedforward waveform's fade, 0 (off) to 1 (on)"),
    PV("SETPOINT_RBV", "ai", "K", 6, "the target the daemon holds (whoever set it; while the heater is off, the "
                                     "last one)"),
    PV("SETPOINT_IN_USE", "ai", "K", 6, "the setpoint in use now, where a ramp has got to (undefined while the "
                                        "loop is open)", per_row=True),
    PV("RAMPING", "bi", "", None, "the setpoint in use is still ramping to the target", choices=("At target",
                                                                                             "Ramping")),
    PV("RAMP_RBV", "ai", "K/min", 4, "the setpoint ramp rate in use (0: steps)"),
    PV("STATE", "mbbi", "", None, "the loop's state (closed-limited: regulating with the heater held at a "
                                  "bound; lost: the IOC has no stream from the daemon)", choices=STATES),
    PV("STABLE", "bi", "", None, "T2's 10 s average within STABLE_TOL of the setpoint for STABLE_HOLD, the ramp "
                                 "done, the loop closed (the rule of cryod's wait_until_stable)",
       choices=("Not stable", "Stable")),
    PV("STABLE_FOR", "ai", "s", 1, "how long T2's 10 s average has been within STABLE_TOL (the daemon's clock)"),
    PV("STABLE_TOL", "ai", "K", 6, "STABLE's tolerance (ioc.stable_tolerance_K)"),
    PV("STABLE_HOLD", "ai", "s", 1, "STABLE's hold time (ioc.stable_hold_s)"),
    PV("ZONE", "longin", "", None, "the zone of control.zones in use (counted from 1; 0 without zones)"),
    PV("LAST_FAULT", "waveform", "", None, "the last fault, in words (empty: none since the start)"),
    PV("SETPOINT_WARNING", "waveform", "", None, "why the heater cannot hold the setpoint asked for (empty: it "
                                                 "can)"),
    PV("ALARMS", "waveform", "", None, "cryod's alarms raised or latched, each with its state and figure "
                                       "(empty: none)"),
    PV("RECORD_PATH", "waveform", "", None, "the record (data file) being written"),
    PV("LATENESS", "ai", "ms", 3, "how late this row's tick started after its deadline", per_row=True),
    PV("LATENESS_P99", "ai", "ms", 3, "the ticks' lateness, 99th percentile since the start"),
    PV("LATENESS_MAX", "ai", "ms", 3, "the ticks' largest lateness since the start"),
    PV("TICKS", "longin", "", None, "the loop's ticks since the start"),
    PV("OVERRUNS", "longin", "", None, "ticks that ended after the next one's deadline, since the start"),
    PV("CONNECTED", "bi", "", None, "the IOC has the daemon's stream (0: every reading is INVALID, COMM)",
       choices=("Lost", "Connected")),
    PV("MESSAGE", "waveform", "", None, "the daemon's answer to the last put (a refusal says why)"),
)

SETTINGS = (
    PV("SETPOINT", "ao", "K", 6, "regulate to this temperature (setpoint K); DRVL/DRVH: control.setpoint_min_K "
                                 "and setpoint_max_K. A put with completion returns when STABLE (or when a newer "
                                 "put, another target, a heater-off or ioc.settle_timeout_s ends the wait)",
       writable=True),
    PV("RAMP", "ao", "K/min", 4, "setpoint ramp rate (ramp K_PER_MIN; 0: steps); DRVH: "
                                 "control.max_ramp_K_per_min", writable=True),
    PV("FEEDFORWARD", "bo", "", None, "switch the feedforward locked to the cooler (feedforward on|off; it fades "
                                      "in or out)", choices=("Off", "On"), writable=True),
    PV("HEATER_OFF", "bo", "", None, "1: heater to 0 W and the loop open (heater-off); 0: regulate again at "
                                     "SETPOINT_RBV when off. Reads 1 while the loop is off",
       choices=("Regulate", "Heater off"), writable=True),
    PV("NOTE", "waveform", "", None, "a line of text into the record being written (note TEXT), with who put it",
       writable=True),
    PV("ALARM_ACK", "waveform", "", None, "acknowledge one of cryod's alarms by name, or all (alarms ack NAME)",
       writable=True),
)

#: Every PV by name.
PVS = {pv.name: pv for pv in READINGS + SETTINGS}

__all__ = ["PV", "PVS", "READINGS", "SETTINGS", "STATES", "LONGEST_NAME"]
