"""Every configured alarm, fed the loop's rows: what is raised, and the changes as they happen.

:class:`AlarmBoard` takes each row's figures (time, state, T2, T5, heater power,
setpoint) and returns the alarms' changes (:class:`~cryod.alarms.latch.Transition`).
T5's alarms are checked at every row; the windowed ones (deviation, stability, heater)
once a second of the daemon's clock, while the loop regulates at a steady setpoint. The
deviation and stability alarms are armed at a setpoint once their figure has been within
its threshold there: the approach to a new setpoint never raises them.

Time is the rows' own (the daemon's clock), so a test or a dry run on virtual time sees
the same alarms as the real cryostat would.

Examples
--------
>>> from cryod.alarms.settings import AlarmsConfig, PtcStageWarmAlarm
>>> board = AlarmBoard(AlarmsConfig(ptc_stage_warm=PtcStageWarmAlarm(threshold_K=4.5, delay_s=1.0)),
...                    heater_max_power_w=0.5, cooler_rad_s=10.83, period_s=0.08)
>>> changes = [change for tick in range(40)
...            for change in board.take(0.08 * tick, "closed", 5.0, 4.0 if tick < 10 else 4.6, 0.1, 5.0)]
>>> [(change.kind, round(change.time_s, 2)) for change in changes]
[('raised', 1.84)]
>>> board.raised()[0]["name"], board.raised()[0]["message"]
('ptc_stage_warm', 'T5 4.6000 K (threshold 4.5 K)')
"""

from __future__ import annotations

import math

from cryod.alarms.conditions import (
    HEATER_AVERAGE_S,
    RecentValues,
    cooler_line_condition,
    covers,
    deviation_condition,
    heater_condition,
    ptc_stage_condition,
    stability_condition,
)
from cryod.alarms.latch import AlarmLatch, Condition, Transition
from cryod.alarms.settings import ALARM_NAMES, MAX_WINDOW_S, AlarmsConfig, DeviationAlarm
from cryod.cooler.phase import CoolerPhaseTracker

#: Loop states in which the loop regulates (the row's ``state``).
REGULATING = ("closed", "closed-limited")
#: The windowed alarms are checked this often, in the daemon's clock (s).
CHECK_INTERVAL_S = 1.0
#: The windowed alarms' condition while the loop does not regulate at a steady setpoint.
NOT_REGULATING = Condition(False, math.nan, "not regulating at a steady setpoint")


class AlarmBoard:
    """The configured alarms and what they need to remember.

    Parameters
    ----------
    config : AlarmsConfig
    heater_max_power_w : float
        R I_max^2 (W), the heater's top.
    cooler_rad_s : float
        The cooler's angular frequency in the model (rad/s), where the line's tracker starts.
    period_s : float
        The loop period (s): sizes the windows.
    """

    def __init__(self, config: AlarmsConfig, heater_max_power_w: float, cooler_rad_s: float, period_s: float):
        self.heater_max_power_w = float(heater_max_power_w)
        self.period_s = float(period_s)
        capacity = int(MAX_WINDOW_S / self.period_s * 1.1) + 16
        self._flange = RecentValues(capacity)
        self._heater = RecentValues(int(HEATER_AVERAGE_S / self.period_s * 1.1) + 16)
        self._tracker = CoolerPhaseTracker(cooler_rad_s, harmonics=1)
        self._cooler_rad_s = cooler_rad_s
        self._setpoint_K = math.nan          # the steady setpoint the windows hold readings at (NaN: none)
        self._armed: set[str] = set()
        self._next_check_s = -math.inf
        self.config = AlarmsConfig()
        self.latches: dict[str, AlarmLatch] = {}
        self.reconfigure(config, math.nan)

    # -- settings ------------------------------------------------------------------------
    def reconfigure(self, config: AlarmsConfig, time_s: float) -> list[Transition]:
        """New settings (a reload): alarms kept keep their state, alarms switched off are cleared."""
        changes = []
        for name in ALARM_NAMES:
            settings = config.settings(name)
            latch = self.latches.get(name)
            if settings is None:
                if latch is not None:
                    change = latch.clear(time_s, "switched off by the configuration")
                    changes += [change] if change is not None else []
                    del self.latches[name]
                continue
            if latch is None:
                self.latches[name] = AlarmLatch(name, settings.delay_s, settings.latching)
            else:
                latch.reconfigure(settings.delay_s, settings.latching)
        if config.cooler_line_lost is not None and self.config.cooler_line_lost is None:
            self._tracker = CoolerPhaseTracker(self._cooler_rad_s, harmonics=1,
                                               minimum_amplitude_K=config.cooler_line_lost.min_amplitude_K)
        elif config.cooler_line_lost is not None:
            self._tracker.minimum_amplitude_K = config.cooler_line_lost.min_amplitude_K
        self.config = config
        self._next_check_s = -math.inf
        return changes

    # -- the rows -------------------------------------------------------------------------
    def take(self, time_s: float, state: str, flange_K: float, ptc_stage_K: float, heater_w: float,
             setpoint_K: float | None) -> list[Transition]:
        """One row's figures; the alarms' changes they make (usually none)."""
        config, latches = self.config, self.latches
        if not latches:
            return []
        changes: list[Transition] = []
        regulating = (state in REGULATING and setpoint_K is not None and math.isfinite(setpoint_K)
                      and math.isfinite(flange_K))
        if not regulating or setpoint_K != self._setpoint_K:
            self._start_windows(setpoint_K if regulating and setpoint_K is not None else math.nan)
        if regulating:
            self._flange.append(time_s, flange_K)
            self._heater.append(time_s, heater_w)
        if config.ptc_stage_warm is not None:
            self._update(changes, "ptc_stage_warm", time_s, ptc_stage_condition(config.ptc_stage_warm, ptc_stage_K))
        if config.cooler_line_lost is not None:
            phase = self._tracker.update(time_s, ptc_stage_K) if math.isfinite(ptc_stage_K) else self._tracker.state
            self._update(changes, "cooler_line_lost", time_s, cooler_line_condition(config.cooler_line_lost, phase))
        if time_s >= self._next_check_s:
            self._next_check_s = time_s + CHECK_INTERVAL_S
            self._check_windows(changes, time_s)
        return changes

    def _start_windows(self, setpoint_K: float) -> None:
        if self._setpoint_K != self._setpoint_K and setpoint_K != setpoint_K:
            return                              # not regulating before or now: nothing to start afresh
        self._setpoint_K = setpoint_K
        self._flange.reset()
        self._heater.reset()
        self._armed.clear()
        self._next_check_s = -math.inf          # at once: leaving regulation clears what needs it

    def _check_windows(self, changes: list[Transition], time_s: float) -> None:
        config, setpoint_K = self.config, self._setpoint_K
        steady = setpoint_K == setpoint_K
        for name, settings in (("deviation", config.deviation), ("stability", config.stability)):
            if settings is None:
                continue
            condition = NOT_REGULATING
            if steady and covers(self._flange, settings.window_s, time_s, self.period_s):
                _, values = self._flange.window(settings.window_s, time_s)
                condition = deviation_condition(settings, values.mean(), setpoint_K, settings.window_s) \
                    if isinstance(settings, DeviationAlarm) else stability_condition(settings, values.std())
                if name not in self._armed:
                    if condition.holds is False:
                        self._armed.add(name)
                    else:
                        condition = Condition(False, condition.value,
                                              f"settling at {setpoint_K:.4f} K: {condition.text}")
            self._update(changes, name, time_s, condition)
        if config.heater_near_top is not None:
            condition = NOT_REGULATING
            if steady and covers(self._heater, HEATER_AVERAGE_S, time_s, self.period_s):
                _, values = self._heater.window(HEATER_AVERAGE_S, time_s)
                condition = heater_condition(config.heater_near_top, values.mean(), self.heater_max_power_w)
            self._update(changes, "heater_near_top", time_s, condition)

    def _update(self, changes: list[Transition], name: str, time_s: float, condition: Condition) -> None:
        change = self.latches[name].update(time_s, condition)
        if change is not None:
            changes.append(change)

    # -- the operator -----------------------------------------------------------------------
    def acknowledge(self, which: str, time_s: float, sender: str = "") -> list[Transition]:
        """Acknowledge one alarm (its name) or every raised one (``all``).

        Raises
        ------
        ValueError
            No such alarm is on, it is not raised, or (``all``) none is raised to acknowledge.
        """
        if which == "all":
            changes = [latch.acknowledge(time_s, sender) for latch in self.latches.values()
                       if latch.raised and not (latch.state == "raised" and latch.acknowledged)]
            if not changes:
                raise ValueError("no alarm is raised that waits for an acknowledgement")
            return changes
        latch = self.latches.get(which)
        if latch is None:
            on = ", ".join(self.latches) or "none (no alarms section in the configuration)"
            raise ValueError(f"no alarm {which!r} is on; alarms on: {on}")
        return [latch.acknowledge(time_s, sender)]

    # -- what stands -------------------------------------------------------------------------
    def alarms(self) -> list[dict]:
        """Every alarm that is on, in :data:`~cryod.alarms.settings.ALARM_NAMES` order (``AlarmLatch.as_dict``)."""
        return [self.latches[name].as_dict() for name in ALARM_NAMES if name in self.latches]

    def raised(self) -> list[dict]:
        """The alarms raised or latched now."""
        return [latch.as_dict() for name, latch in self.latches.items() if latch.raised]
