"""The reading records of the IOC (softioc), and their updates with the daemon's own sample instants.

Each reading of :data:`~cryod.ioc.pv_table.READINGS` is an input record scanned on I/O interrupt:
:class:`ReadingRecords` sets its value, its alarm (:mod:`cryod.ioc.alarm_severity`) and its
timestamp. The timestamp is the daemon's (the records' TSE is -2, "device time"): a row's is the
instant of its readings on the daemon's monotonic clock (``time_s``) plus the offset to the wall
clock the stream's first line gives (``clock_offset_s``), the same time the record file and the web
page show; a status figure's is the latest row's. So a reading archived or plotted in EPICS is at the
time it was taken, not when the IOC passed it on.
"""

from __future__ import annotations

import math

from softioc import builder

from cryod.ioc.alarm_severity import (INVALID, MAJOR, NO_ALARM, STAT_COMM, STAT_NONE, STAT_STATE, STAT_UDF,
                                      STATE_SEVERITY, pv_alarms)
from cryod.ioc.pv_table import PV, READINGS, STATES
from cryod.records.columns import Row
from cryod.service.daemon_status import DaemonStatus
from cryod.service.settling import Settling

#: Characters a text reading holds (its waveform's NELM).
TEXT_LENGTH = {"ALARMS": 4096, "RECORD_PATH": 1024}
DEFAULT_TEXT_LENGTH = 1024
#: "Device time": the record's timestamp is the one its device support sets (the daemon's sample instant).
DEVICE_TIME = -2


def build_record(prefix: str, pv: PV, **fields):
    """The softioc record of ``pv`` (name, type, EGU, PREC, labels), with ``fields`` added."""
    name = prefix + pv.name
    fields = dict(fields, DESC=pv.meaning[:40])
    if pv.record in ("ai", "ao"):
        fields.update(EGU=pv.unit, PREC=pv.precision)
    if pv.record == "ai":
        return builder.aIn(name, **{"initial_value": math.nan, **fields})
    if pv.record == "ao":
        return builder.aOut(name, **fields)
    if pv.record == "bi":
        return builder.boolIn(name, *pv.choices, **fields)
    if pv.record == "bo":
        return builder.boolOut(name, *pv.choices, **fields)
    if pv.record == "mbbi":
        return builder.mbbIn(name, *pv.choices, **fields)
    if pv.record == "longin":
        return builder.longIn(name, EGU=pv.unit or None, **fields)
    if pv.record == "waveform" and pv.writable:
        return builder.longStringOut(name, length=TEXT_LENGTH.get(pv.name, DEFAULT_TEXT_LENGTH), **fields)
    if pv.record == "waveform":
        return builder.longStringIn(name, length=TEXT_LENGTH.get(pv.name, DEFAULT_TEXT_LENGTH), **fields)
    raise ValueError(f"{pv.name}: no record type {pv.record!r}")


class ReadingRecords:
    """The reading records, built before ``iocInit``.

    Parameters
    ----------
    prefix : str
        ``ioc.prefix``.
    constants : dict
        Readings that do not change while the IOC runs (HEATER_MAX, STABLE_TOL, STABLE_HOLD), by name.
    elsewhere : set of str
        Readings set by other parts of the IOC (MESSAGE, by the puts), stamped with the IOC's clock.
    """

    def __init__(self, prefix: str, constants: dict[str, float], elsewhere: set[str] = frozenset()):
        self.records = {}
        for pv in READINGS:
            fields = {"TSE": DEVICE_TIME}
            if pv.name in constants:
                fields = {"initial_value": constants[pv.name]}
            elif pv.name in elsewhere:
                fields = {}
            self.records[pv.name] = build_record(prefix, pv, **fields)
        self.per_row = [pv.name for pv in READINGS if pv.per_row]
        self.per_status = [pv.name for pv in READINGS
                           if not pv.per_row and pv.name not in constants and pv.name not in elsewhere]
        self.clock_offset_s = 0.0
        #: Severity and STAT of the per-row PVs, from the last status (their alarms change with the status).
        self._row_alarms: dict[str, tuple[int, int]] = {}
        #: What each record shows: (value, severity, STAT); a status reading is set again only when it changes.
        self._shown: dict[str, tuple] = {}
        self._latest_time_s = math.nan

    def _wall(self, time_s: float) -> float | None:
        """A daemon clock time as wall-clock seconds since 1970 (None: not a time)."""
        return time_s + self.clock_offset_s if math.isfinite(time_s) else None

    def row(self, row: Row, values: dict[str, float]) -> None:
        """One row's readings, stamped with its sample instant."""
        self._latest_time_s = row.time_s
        stamp = self._wall(row.time_s)
        for name in self.per_row:
            severity, stat = self._row_alarms.get(name, (NO_ALARM, STAT_NONE))
            self.records[name].set(values[name], severity=severity, alarm=stat, timestamp=stamp)
            self._shown[name] = (values[name], severity, stat)

    def status(self, status: DaemonStatus, settling: Settling, values: dict[str, object]) -> None:
        """The status' readings and every reading's alarm, as of the latest row."""
        loop = status.loop
        average = status.recent.flange_average_K if status.recent is not None else math.nan
        above = None if loop.setpoint_K is None or not math.isfinite(average) else average > loop.setpoint_K
        alarms = pv_alarms(status.alarms, above)
        if status.waiting_for is not None:
            alarms = {name: (INVALID, STAT_UDF) for name in self.per_row + self.per_status}
        state = STATES[int(values["STATE"])]
        if state in STATE_SEVERITY:
            alarms["STATE"] = (STATE_SEVERITY[state], STAT_STATE)
        self._row_alarms = {name: alarms.get(name, (NO_ALARM, STAT_NONE)) for name in self.per_row}
        time_s = loop.time_s if math.isfinite(loop.time_s) else self._latest_time_s
        stamp = self._wall(time_s)
        for name in self.per_status:
            severity, stat = alarms.get(name, (NO_ALARM, STAT_NONE))
            self._show(name, values[name], severity, stat, stamp)
        for name, (severity, stat) in self._row_alarms.items():
            shown = self._shown.get(name)
            if shown is not None and shown[1:] != (severity, stat):   # an alarm that came or went between two rows
                self._show(name, shown[0], severity, stat, stamp)

    def _show(self, name: str, value, severity: int, stat: int, stamp: float | None) -> None:
        """Set a record when its value or alarm changed (a monitor then gets it once)."""
        shown = self._shown.get(name)
        if shown is not None and shown[1:] == (severity, stat) and _same(shown[0], value):
            return
        self.records[name].set(value, severity=severity, alarm=stat, timestamp=stamp)
        self._shown[name] = (value, severity, stat)

    def message(self, text: str) -> None:
        """MESSAGE: the daemon's answer to the last put (any thread)."""
        self.records["MESSAGE"].set(text[:DEFAULT_TEXT_LENGTH - 1])

    def lost(self) -> None:
        """The stream from the daemon is gone: every changing reading INVALID, COMM, holding its last value."""
        for name in self.per_row + self.per_status:
            value = self._shown.get(name, (self.records[name].get(),))[0]
            if name == "CONNECTED":
                self._show(name, 0, MAJOR, STAT_COMM, None)
            elif name == "STATE":
                self._show(name, STATES.index("lost"), INVALID, STAT_COMM, None)
            else:
                self._show(name, value, INVALID, STAT_COMM, None)
        self._row_alarms = {name: (INVALID, STAT_COMM) for name in self.per_row}


def _same(a, b) -> bool:
    """Equal values, NaN equal to NaN."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


__all__ = ["ReadingRecords", "build_record"]
