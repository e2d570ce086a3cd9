"""The daemon's status as one typed, immutable object, and the one function that turns it into JSON.

Everything that shows the daemon reads a :class:`DaemonStatus`: the control socket's ``status``
(``cryod ctl status``), the live stream, the web page, the Lake Shore 336 command set, the Python
client's waits. It is built from the loop's :class:`LoopStatus` (the last tick: readings, heater,
setpoint, state, the control terms' columns, timing) and what the daemon adds (the record, the
alarms, the interfaces, the figures of the recent past). :func:`status_json` is the only place
its fields become the JSON keys users and checks rely on (``T2_K``, ``setpoint_K``, ``state``,
``record_path``, ...); :func:`status_from_json` reads them back, for the processes that get the
status as JSON (the interfaces process, the client).

Examples
--------
>>> loop = LoopStatus(time_s=12.0, state="closed", flange_K=5.0001, ptc_stage_K=3.4, heater_w=0.113,
...                   setpoint_K=5.0, target_K=5.0, last_target_K=5.0)
>>> status = DaemonStatus(loop=loop, record_path="/var/lib/cryod/cryod-2026-12-07.csv")
>>> data = status_json(status)
>>> data["T2_K"], data["state"], data["record_path"]
(5.0001, 'closed', '/var/lib/cryod/cryod-2026-12-07.csv')
>>> status_from_json(data) == status
True
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any, Mapping


def _frozen(mapping: Mapping | None = None) -> Mapping:
    """A read-only view of a copy of ``mapping`` (an empty one for None)."""
    return MappingProxyType(dict(mapping or {}))


@dataclass(frozen=True)
class TimingFigures:
    """The loop's timing as the status gives it (:meth:`cryod.service.timing.LoopTiming.figures`)."""

    ticks: int = 0
    overruns: int = 0
    missed_deadlines: int = 0
    #: Cycles that ended late while the heater was off waiting for valid readings: not overruns.
    late_cycles_waiting_for_instruments: int = 0
    lateness_ms_p50: float = 0.0
    lateness_ms_p99: float = 0.0
    lateness_ms_max: float = 0.0
    gc_ms_max: float = 0.0


#: The JSON keys of :class:`TimingFigures`: its field names.
TIMING_KEYS = tuple(item.name for item in fields(TimingFigures))


@dataclass(frozen=True)
class LoopStatus:
    """The loop as of its last tick (built when asked, from the tick's snapshot; never changed after).

    Attributes
    ----------
    time_s : float
        The daemon's clock at the tick's readings (s).
    state : str
        The loop's state (:class:`cryod.service.states.LoopState`), or ``waiting`` before the loop runs.
    flange_K, ptc_stage_K : float
        T2 and T5 (K).
    heater_w : float
        The heater power the supply was told (W); NaN: unknown (the supply could not be switched off).
    setpoint_K, target_K : float or None
        The setpoint in use while regulating; the target once one is asked for.
    ramp_K_per_min : float
    last_fault : str or None
    last_target_K : float or None
        The last target given, kept while the loop is open: what regulating again heads for.
    control : mapping
        The control terms' columns of the last tick (``pi_proportional_W``, ``ff_line_K``, ...).
    zone, zone_upper_K : int, float or None
        The zone in use (counted from 1) and its upper temperature; None without ``control.zones``.
    timing : TimingFigures
    """

    time_s: float = math.nan
    state: str = "holding"
    flange_K: float = math.nan
    ptc_stage_K: float = math.nan
    heater_w: float = 0.0
    setpoint_K: float | None = None
    target_K: float | None = None
    ramp_K_per_min: float = 0.0
    last_fault: str | None = None
    last_target_K: float | None = None
    control: Mapping[str, Any] = field(default_factory=_frozen)
    zone: int | None = None
    zone_upper_K: float | None = None
    timing: TimingFigures = TimingFigures()

    def __post_init__(self):
        object.__setattr__(self, "state", str(self.state))
        if not isinstance(self.control, MappingProxyType):
            object.__setattr__(self, "control", _frozen(self.control))

    def one_line(self) -> str:
        """Short text for systemd STATUS=."""
        setpoint = f"{self.setpoint_K:.4f} K" if self.setpoint_K is not None else "none"
        heater = f"{self.heater_w * 1e3:.2f} mW" if math.isfinite(self.heater_w) else "UNKNOWN"
        zone = f" (zone {self.zone})" if self.zone is not None else ""
        text = (f"{self.state}: T2 {self.flange_K:.5f} K, setpoint {setpoint}{zone}, heater {heater}, "
                f"overruns {self.timing.overruns}")
        if self.last_fault:
            text += f"; last fault: {self.last_fault}"
        return text


@dataclass(frozen=True)
class RecentFigures:
    """What the last seconds of rows say: T2 averaged over 10 s, the cooler line's amplitude on T2 (K), the
    heater's level (its power over the last whole cooler cycles, W); NaN until there is enough. Computed by
    whoever holds the rows (the daemon for ``cryod ctl``, the interfaces process for what it serves), so the
    stream can leave them out."""

    flange_average_K: float = math.nan
    line_amplitude_K: float = math.nan
    heater_mean_W: float = math.nan


@dataclass(frozen=True)
class DaemonStatus:
    """What ``cryod ctl status`` says of the daemon.

    Attributes
    ----------
    loop : LoopStatus
        The last tick (state ``waiting`` before the loop runs).
    waiting_for : str or None
        Before the loop runs: what the daemon waits for (opening the instruments); None once it runs.
    record_path : str or None
        The record being written.
    setpoint_warning : str or None
        Why the heater cannot hold the setpoint asked for.
    alarms : tuple of mapping
        The alarms raised or latched (:meth:`cryod.service.alarms.AlarmMonitor.raised`).
    alarm_states : mapping
        1.0 for each alarm raised or latched, 0.0 for the others that are on.
    interfaces : mapping or None
        The interfaces process: running, where it serves, its problems (None: none configured).
    recent : RecentFigures or None
        The figures of the recent past; None where they are left to the reader (the stream).
    flange_ohm, ptc_stage_ohm : float or None
        The thermometers' resistances of the last row (the 336's ``SRDG?``); not part of the JSON.
    """

    loop: LoopStatus = LoopStatus(state="waiting", heater_w=math.nan)
    waiting_for: str | None = None
    record_path: str | None = None
    setpoint_warning: str | None = None
    alarms: tuple[Mapping[str, Any], ...] = ()
    alarm_states: Mapping[str, float] = field(default_factory=_frozen)
    interfaces: Mapping[str, Any] | None = None
    recent: RecentFigures | None = None
    flange_ohm: float | None = None
    ptc_stage_ohm: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "alarms", tuple(_frozen(alarm) for alarm in self.alarms))
        if not isinstance(self.alarm_states, MappingProxyType):
            object.__setattr__(self, "alarm_states", _frozen(self.alarm_states))
        if self.interfaces is not None and not isinstance(self.interfaces, MappingProxyType):
            object.__setattr__(self, "interfaces", _frozen(self.interfaces))

    @property
    def regulating(self) -> bool:
        """The loop regulates to a setpoint (``closed``, also when held at a heater bound)."""
        return self.loop.state.startswith("closed")


def status_json(status: DaemonStatus) -> dict:
    """The status as every interface sends it (``cryod ctl status --json``'s ``status``, the web page's
    ``/api/status``, the stream's lines): the one place its fields get their keys. NaN stays NaN here (the
    senders write it as null)."""
    extra = {"alarm_states": dict(status.alarm_states),
             "interfaces": None if status.interfaces is None else dict(status.interfaces)}
    if status.waiting_for is not None:
        return {"state": "waiting", "message": status.waiting_for, "heater_W": None,
                "record_path": status.record_path, **extra}
    loop = status.loop
    data = {"time_s": loop.time_s, "state": loop.state, "T2_K": loop.flange_K, "T5_K": loop.ptc_stage_K,
            "heater_W": loop.heater_w, "setpoint_K": loop.setpoint_K, "target_K": loop.target_K,
            "ramp_K_per_min": loop.ramp_K_per_min, "last_target_K": loop.last_target_K,
            "last_fault": loop.last_fault, **loop.control}
    if loop.zone is not None:
        data.update(zone=loop.zone, zone_upper_K=loop.zone_upper_K)
    data.update({key: getattr(loop.timing, key) for key in TIMING_KEYS})
    data.update(record_path=status.record_path, setpoint_warning=status.setpoint_warning,
                alarms=[dict(alarm) for alarm in status.alarms], **extra)
    if status.recent is not None:
        data.update(T2_average_K=status.recent.flange_average_K, line_amplitude_K=status.recent.line_amplitude_K,
                    heater_mean_W=status.recent.heater_mean_W)
    return data


#: The keys of :func:`status_json` that are not a control term's column.
_LOOP_KEYS = {"time_s", "state", "T2_K", "T5_K", "heater_W", "setpoint_K", "target_K", "ramp_K_per_min",
              "last_target_K", "last_fault", "zone", "zone_upper_K", *TIMING_KEYS, "record_path", "setpoint_warning",
              "alarms", "alarm_states", "interfaces", "T2_average_K", "line_amplitude_K", "heater_mean_W", "message"}


def _number(value) -> float:
    """A JSON number as the status holds it (null: NaN)."""
    return math.nan if value is None else float(value)


def status_from_json(data: Mapping[str, Any]) -> DaemonStatus:
    """The status from its JSON (:func:`status_json`'s keys; null numbers as NaN), for those that receive it."""
    extra: dict[str, Any] = {"record_path": data.get("record_path"), "alarm_states": data.get("alarm_states") or {},
             "interfaces": data.get("interfaces")}
    if data.get("state") == "waiting":
        return DaemonStatus(waiting_for=str(data.get("message") or ""), **extra)
    timing = TimingFigures(**{key: data.get(key, getattr(TimingFigures, key)) for key in TIMING_KEYS})
    loop = LoopStatus(time_s=_number(data.get("time_s")), state=str(data.get("state", "")),
                      flange_K=_number(data.get("T2_K")), ptc_stage_K=_number(data.get("T5_K")),
                      heater_w=_number(data.get("heater_W")), setpoint_K=data.get("setpoint_K"),
                      target_K=data.get("target_K"), ramp_K_per_min=data.get("ramp_K_per_min") or 0.0,
                      last_fault=data.get("last_fault"), last_target_K=data.get("last_target_K"),
                      control={key: value for key, value in data.items() if key not in _LOOP_KEYS},
                      zone=data.get("zone"), zone_upper_K=data.get("zone_upper_K"), timing=timing)
    recent = None
    if "T2_average_K" in data or "line_amplitude_K" in data:
        recent = RecentFigures(_number(data.get("T2_average_K")), _number(data.get("line_amplitude_K")),
                               _number(data.get("heater_mean_W")))
    return DaemonStatus(loop=loop, setpoint_warning=data.get("setpoint_warning"),
                        alarms=tuple(data.get("alarms") or ()), recent=recent, **extra)


__all__ = ["DaemonStatus", "LoopStatus", "RecentFigures", "TimingFigures", "status_json", "status_from_json"]
