"""The ``alarms`` section of the configuration: which alarms are on, their thresholds, and the lab's hook.

Absent or null, no alarm is on; inside it, each alarm is on when its own section is
there. Every key is checked like the rest of the configuration: an error names the
file, the line and the key.

Examples
--------
>>> from cryod.yaml_source import Section
>>> section = Section.from_text('''
... alarms:
...   deviation: {threshold_K: 1.0e-4, delay_s: 30}
...   cooler_line_lost: {}
... ''', "lab.yaml")
>>> alarms = alarms_from_section(section.section("alarms"), ptc_stage_max_K=15.0)
>>> alarms.names
('deviation', 'cooler_line_lost')
>>> alarms.deviation.window_s, alarms.cooler_line_lost.min_amplitude_K
(10.0, 0.03)
"""

from __future__ import annotations

import os
import shlex
import shutil
from dataclasses import dataclass, fields
from pathlib import Path

from cryod.yaml_source import Section, shown

#: The alarms, in the order they are listed everywhere (status, metrics, ``cryod ctl alarms``).
ALARM_NAMES = ("deviation", "stability", "ptc_stage_warm", "heater_near_top", "cooler_line_lost")
#: Longest averaging window an alarm may have (s): an hour of rows is kept at most.
MAX_WINDOW_S = 3600.0
#: Longest delay before an alarm is raised (s): a day.
MAX_DELAY_S = 86400.0


@dataclass(frozen=True)
class FlangeWindowAlarm:
    """A figure of T2 over the last ``window_s`` above ``threshold_K`` for ``delay_s``, while regulating at a
    steady setpoint; cleared at or below ``threshold_K - deadband_K``."""

    threshold_K: float
    window_s: float = 10.0
    delay_s: float = 60.0
    deadband_K: float = 0.0
    latching: bool = False


@dataclass(frozen=True)
class DeviationAlarm(FlangeWindowAlarm):
    """T2 averaged over ``window_s`` further than ``threshold_K`` from the setpoint."""


@dataclass(frozen=True)
class StabilityAlarm(FlangeWindowAlarm):
    """T2's standard deviation over ``window_s`` above ``threshold_K``."""

    window_s: float = 60.0
    delay_s: float = 0.0


@dataclass(frozen=True)
class PtcStageWarmAlarm:
    """T5 above ``threshold_K`` for ``delay_s`` (below ``safety.ptc_stage_max_K``, whose fault stops the
    daemon); cleared at or below ``threshold_K - deadband_K``."""

    threshold_K: float
    delay_s: float = 5.0
    deadband_K: float = 0.0
    latching: bool = False


@dataclass(frozen=True)
class HeaterNearTopAlarm:
    """The heater power, averaged over 10 s, at or above ``fraction`` of R I_max^2 for ``delay_s`` while
    regulating; cleared below ``fraction - deadband``. The delay outlasts the minutes a step up to a new
    setpoint holds the heater at its top: the alarm says the heater stays there."""

    fraction: float = 0.95
    delay_s: float = 300.0
    deadband: float = 0.0
    latching: bool = False


@dataclass(frozen=True)
class CoolerLineLostAlarm:
    """The cooler's line on T5 lost for ``delay_s``: its amplitude below ``min_amplitude_K`` or no steady
    phase to lock to (the cooler stopped, or the T5 thermometer no longer sees it)."""

    min_amplitude_K: float = 0.03
    delay_s: float = 10.0
    latching: bool = True


@dataclass(frozen=True)
class AlarmHook:
    """The lab's own command, run on every raised, cleared or acknowledged alarm (details in its environment
    and as JSON on its standard input); at most once per ``min_interval_s`` for each alarm, ended after
    ``timeout_s``."""

    command: tuple[str, ...]
    timeout_s: float = 10.0
    min_interval_s: float = 60.0


@dataclass(frozen=True)
class AlarmsConfig:
    """The ``alarms`` section: each alarm's settings, None when it is off, and the hook."""

    deviation: DeviationAlarm | None = None
    stability: StabilityAlarm | None = None
    ptc_stage_warm: PtcStageWarmAlarm | None = None
    heater_near_top: HeaterNearTopAlarm | None = None
    cooler_line_lost: CoolerLineLostAlarm | None = None
    hook: AlarmHook | None = None

    @property
    def names(self) -> tuple[str, ...]:
        """The alarms that are on, in :data:`ALARM_NAMES` order."""
        return tuple(name for name in ALARM_NAMES if getattr(self, name) is not None)

    def settings(self, name: str):
        """One alarm's settings (None when it is off)."""
        return getattr(self, name)


def _delay(section: Section, default: float) -> float:
    return section.number("delay_s", default, minimum=0.0, maximum=MAX_DELAY_S)


def _window(section: Section, default: float) -> float:
    return section.number("window_s", default, minimum=1.0, maximum=MAX_WINDOW_S)


def _deadband(section: Section, key: str, threshold: float) -> float:
    deadband = section.number(key, 0.0, minimum=0.0)
    if deadband >= threshold:
        raise section.error(key, f"{deadband:g} is not below the threshold ({threshold:g}): the alarm could "
                                 f"never clear")
    return deadband


def _flange_window(kind: type[FlangeWindowAlarm]):
    """The reader of a windowed alarm's section (``deviation`` or ``stability``), with that kind's defaults."""
    def read(section: Section) -> FlangeWindowAlarm:
        threshold = section.number("threshold_K", minimum=0.0, exclusive_minimum=True, maximum=10.0)
        defaults = kind(threshold_K=threshold)
        return kind(threshold_K=threshold, window_s=_window(section, defaults.window_s),
                    delay_s=_delay(section, defaults.delay_s), deadband_K=_deadband(section, "deadband_K", threshold),
                    latching=section.flag("latching", False))
    return read


def _ptc_stage_warm(section: Section, ptc_stage_max_K: float) -> PtcStageWarmAlarm:
    threshold = section.number("threshold_K", minimum=0.0, exclusive_minimum=True)
    if threshold >= ptc_stage_max_K:
        raise section.error("threshold_K", f"{threshold:g} K is not below safety.ptc_stage_max_K "
                                           f"({ptc_stage_max_K:g} K): that fault switches the heater off and stops "
                                           f"the daemon first, so this alarm could never be raised")
    return PtcStageWarmAlarm(threshold_K=threshold, delay_s=_delay(section, 5.0),
                             deadband_K=_deadband(section, "deadband_K", threshold),
                             latching=section.flag("latching", False))


def _heater_near_top(section: Section) -> HeaterNearTopAlarm:
    fraction = section.number("fraction", 0.95, minimum=0.0, exclusive_minimum=True, maximum=1.0)
    return HeaterNearTopAlarm(fraction=fraction, delay_s=_delay(section, 300.0),
                              deadband=_deadband(section, "deadband", fraction),
                              latching=section.flag("latching", False))


def _cooler_line_lost(section: Section) -> CoolerLineLostAlarm:
    return CoolerLineLostAlarm(
        min_amplitude_K=section.number("min_amplitude_K", 0.03, minimum=0.0, exclusive_minimum=True, maximum=10.0),
        delay_s=_delay(section, 10.0), latching=section.flag("latching", True))


def _command(section: Section) -> tuple[str, ...]:
    """The hook's command: a list of words, or one line split as a shell would (no shell runs it)."""
    if isinstance(section.data.get("command"), list):
        words = tuple(section.texts("command"))
    else:
        text = section.text("command")
        try:
            words = tuple(shlex.split(text))
        except ValueError as error:
            raise section.error("command", f"cannot be split into words ({error}): {shown(text)}") from None
    if not words or not words[0].strip():
        raise section.error("command", "is empty: give the program to run and its arguments")
    if any("\0" in word for word in words):
        raise section.error("command", "contains a NUL character")
    program = words[0]
    if os.sep in program:
        path = Path(program).expanduser()
        if not path.is_absolute():
            raise section.error("command", f"{shown(program)}: give the program's absolute path, or a name "
                                           f"found on PATH")
        if not path.is_file() or not os.access(path, os.X_OK):
            raise section.error("command", f"{path} is not an executable file")
        words = (str(path), *words[1:])
    elif shutil.which(program) is None:
        raise section.error("command", f"{shown(program)} is not found on PATH ({os.environ.get('PATH', '')}); "
                                       f"give its absolute path")
    return words


def _hook(section: Section) -> AlarmHook:
    return AlarmHook(command=_command(section),
                     timeout_s=section.number("timeout_s", 10.0, minimum=0.1, maximum=600.0),
                     min_interval_s=section.number("min_interval_s", 60.0, minimum=0.0, maximum=MAX_DELAY_S))


def alarms_from_section(section: Section | None, ptc_stage_max_K: float) -> AlarmsConfig:
    """Validate the ``alarms`` section (None: no alarm is on).

    Parameters
    ----------
    section : Section or None
    ptc_stage_max_K : float
        ``safety.ptc_stage_max_K``: the stage alarm's threshold must lie below it.

    Returns
    -------
    AlarmsConfig

    Raises
    ------
    cryod.yaml_source.FileFormatError
        At the file, line and key of what is wrong.
    """
    if section is None:
        return AlarmsConfig()
    readers = {"deviation": _flange_window(DeviationAlarm), "stability": _flange_window(StabilityAlarm),
               "ptc_stage_warm": lambda part: _ptc_stage_warm(part, ptc_stage_max_K),
               "heater_near_top": _heater_near_top, "cooler_line_lost": _cooler_line_lost, "hook": _hook}
    values = {}
    for field in fields(AlarmsConfig):
        part = section.section(field.name, None)
        if part is not None:
            values[field.name] = readers[field.name](part)
            part.finish()
    section.finish()
    return AlarmsConfig(**values)


__all__ = ["ALARM_NAMES", "AlarmsConfig", "AlarmHook", "alarms_from_section"]
