"""The regulator: one control law for the daemon's loop and for the offline closed-loop simulation.

Each tick it turns the readings into the heater power for the coming period:

1. in mode ``off`` the power is 0 W; in ``manual`` it is the power set by hand (a constant, or a
   sinusoid about a mean: :class:`HeaterModulation`, for identification experiments);
2. in ``closed`` the setpoint ramp advances, every control term
   (:mod:`cryod.control.terms`) gives its part, the sum is held within the
   heater's range (0 to R * I_max**2: the heater can only heat and its current
   is limited) and every term is told what was applied (anti-windup). Terms
   that ride on the feedback (``rides_on_feedback``: the feedforward's
   waveform) are added after the feedback terms' sum has been held and told,
   and the total is held again: a waveform clipped at 0 W does not stop PI
   integrating;
3. closing the loop from any mode is bumpless: the terms continue from the
   power that was applied.

It knows neither instruments nor clocks: :class:`cryod.service.loop.ControlLoop`
schedules it, handles faults and does the I/O;
:func:`cryod.control.closed_loop.run_program` drives it on the simulated cryostat.

Examples
--------
>>> from cryod.config import EXAMPLE_CONFIG_PATH, load_config
>>> config = load_config(EXAMPLE_CONFIG_PATH)
>>> regulator = Regulator(config.control, HeaterPowerOutput(config.heater.max_power_w))
>>> regulator.mode
<RegulatorMode.CLOSED: 'closed'>
>>> regulator.close_loop(0.0, flange_K=4.99, ptc_stage_K=3.3, present_power_w=0.0)
>>> step = regulator.step(0.08, dt_s=0.08, flange_K=4.99, ptc_stage_K=3.3)
>>> round(step.power_w, 5), step.setpoint_K, step.limited      # Kp * 0.01 K, plus 0.08 s of integral
(0.10016, 5.0, False)
>>> step = regulator.step(0.16, dt_s=0.08, flange_K=4.9, ptc_stage_K=3.3)
>>> round(step.power_w, 9), step.limited                       # Kp * 0.1 K is more than R * I_max^2
(0.5, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, NamedTuple

from cryod.control.ramp import SetpointRamp
from cryod.control.terms import ControlTerm, TickInputs, build_terms, term_columns

if TYPE_CHECKING:
    from cryod.control.zones import ZoneTable


@dataclass(frozen=True)
class ControlConfig:
    """The regulator's settings, the configuration's ``control`` section: setpoint, ramp, their limits,
    and each control term's own section (read by :mod:`cryod.config`).

    Attributes
    ----------
    terms : tuple of (str, settings)
        Each control term's name and validated settings, from its section
        (``control.pi``, ...), in the order of :data:`cryod.control.terms.TERM_TYPES`.
    """

    setpoint_K: float | None
    ramp_K_per_min: float
    setpoint_min_K: float
    setpoint_max_K: float
    max_ramp_K_per_min: float
    terms: tuple = ()
    #: The zones (``control.zones``), or None: the terms' own settings at every temperature.
    zones: ZoneTable | None = None

    def term(self, name: str):
        """The settings of the control term ``name``."""
        return dict(self.terms)[name]


class RegulatorMode(StrEnum):
    """What sets the heater: the control terms, a power set by hand, or nothing."""

    CLOSED = "closed"
    MANUAL = "manual"
    OFF = "off"


class HeaterPowerOutput:
    """The regulator's output is the heater power (W), 0 to ``max_power_w`` (cryod's own loop).

    Parameters
    ----------
    max_power_w : float
        R * I_max**2 (W).
    """

    unit = "W"

    def __init__(self, max_power_w: float):
        if not max_power_w > 0.0:
            raise ValueError(f"the heater's maximum power must be > 0 W, got {max_power_w}")
        self.max_power_w = float(max_power_w)
        self.maximum = self.max_power_w

    def power_w(self, output: float) -> float:
        return output

    def output_for(self, power_w: float) -> float:
        return power_w


class HeaterCurrentOutput:
    """The output is the heater current (A), 0 to I_max; the power is R I**2.

    For comparing with controllers whose output is a current (the gains are
    then in A/K and A/(K s)); cryod's own loop outputs power.

    Parameters
    ----------
    resistance_ohm : float
    max_power_w : float
        R * I_max**2 (W).
    """

    unit = "A"

    def __init__(self, resistance_ohm: float, max_power_w: float):
        if not (resistance_ohm > 0.0 and max_power_w > 0.0):
            raise ValueError(f"need a heater resistance and maximum power > 0, got {resistance_ohm}, {max_power_w}")
        self.resistance_ohm = float(resistance_ohm)
        self.max_power_w = float(max_power_w)
        self.maximum = math.sqrt(max_power_w / resistance_ohm)

    def power_w(self, output: float) -> float:
        return self.resistance_ohm * output * output

    def output_for(self, power_w: float) -> float:
        return math.sqrt(power_w / self.resistance_ohm)


class HeaterModulation:
    """A heater power ``mean_w + amplitude_w * sin(w (t - t0))`` in W, t0 the first instant it is asked for.

    Examples
    --------
    >>> modulation = HeaterModulation(0.02, 0.01, angular_frequency_rad_s=math.pi / 2)
    >>> modulation.power_w(10.0), round(modulation.power_w(11.0), 6)
    (0.02, 0.03)
    """

    def __init__(self, mean_w: float, amplitude_w: float, angular_frequency_rad_s: float):
        if not (math.isfinite(mean_w) and math.isfinite(amplitude_w) and amplitude_w >= 0.0
                and angular_frequency_rad_s > 0.0 and math.isfinite(angular_frequency_rad_s)):
            raise ValueError(f"a heater modulation needs a finite mean, an amplitude >= 0 and an angular frequency "
                             f"> 0, got {mean_w!r} W, {amplitude_w!r} W, {angular_frequency_rad_s!r} rad/s")
        self.mean_w = float(mean_w)
        self.amplitude_w = float(amplitude_w)
        self.angular_frequency_rad_s = float(angular_frequency_rad_s)
        self.start_s: float | None = None

    def power_w(self, time_s: float) -> float:
        """The power at ``time_s`` (s); the first call sets the start of the phase."""
        if self.start_s is None:
            self.start_s = time_s
        return self.mean_w + self.amplitude_w * math.sin(self.angular_frequency_rad_s * (time_s - self.start_s))


class RegulatorStep(NamedTuple):
    """One tick's result.

    Attributes
    ----------
    power_w : float
        Heater power for the coming period (W).
    setpoint_K : float
        Setpoint after the ramp (K); NaN when the loop is open.
    limited : bool
        The terms asked for more than the heater's range allowed (or less than 0).
    columns : dict of str to float
        The control terms' record columns (empty when the loop is open).
    events : tuple of (str, int, str)
        What the terms had to say this tick: (term name, logging level, text).
    """

    power_w: float
    setpoint_K: float
    limited: bool
    columns: dict
    events: tuple = ()


class Regulator:
    """The control terms, the setpoint ramp, the mode and the heater's range.

    Parameters
    ----------
    control : ControlConfig
        The ``control`` section: setpoint, ramp, and each term's settings.
    output : HeaterPowerOutput or HeaterCurrentOutput
        What the terms' outputs are and their range.
    """

    def __init__(self, control: ControlConfig, output: HeaterPowerOutput | HeaterCurrentOutput):
        self.output = output
        self.control = control
        self.terms: list[ControlTerm] = build_terms(control.terms, output.maximum)
        self._riding = [term for term in self.terms if term.rides_on_feedback]
        self._column_names = [(term, tuple(column.name for column in term.columns)) for term in self.terms]
        self._feedback = [term for term in self.terms if term not in self._riding]
        self.columns = term_columns(control.terms)
        self.ramp = SetpointRamp(control.setpoint_K or 0.0, control.ramp_K_per_min)
        self.mode = RegulatorMode.CLOSED if control.setpoint_K is not None else RegulatorMode.OFF
        #: The terms run on the ramp's setpoint: the loop was closed (:meth:`close_loop`) and not opened since.
        #: False while the mode is closed but the loop waits for valid readings to close it.
        self.regulating = False
        self.manual_power_w = 0.0
        self.modulation: HeaterModulation | None = None      # manual mode: a sinusoid instead of a constant
        self._feedback_offset_K = 0.0       # T2 less what the feedback terms saw of it, last tick
        #: The range the terms' sum is held within: R * I_max**2, or the zone's heater limit.
        self.maximum = output.maximum
        #: The zone in use (index into ``control.zones``), None without zones.
        self.zone_index: int | None = None
        self._zone_events: list[str] = []
        if control.zones is not None:
            self._enter_zone(control.zones, control.zones.index_for(self.ramp.setpoint_K), "start")

    # -- the cycle ---------------------------------------------------------------
    def step(self, time_s: float, dt_s: float, flange_K: float, ptc_stage_K: float, *,
             flange_time_s: float | None = None, ptc_stage_time_s: float | None = None,
             output_time_s: float | None = None) -> RegulatorStep:
        """The heater power for the coming period from this tick's readings.

        Parameters
        ----------
        time_s : float
            Clock time of the readings' trigger (s).
        dt_s : float
            Time since the previous readings (s).
        flange_K, ptc_stage_K : float
            T2 and T5 (K).
        flange_time_s, ptc_stage_time_s : float, optional
            The instants the readings stand for (default: ``time_s``).
        output_time_s : float, optional
            When the power returned takes effect (default: ``time_s``).
        """
        tick = TickInputs.at(time_s, dt_s, flange_K, ptc_stage_K, self.ramp.setpoint_K, flange_time_s,
                             ptc_stage_time_s, output_time_s)
        for term in self.terms:        # every mode: a phase tracker keeps its lock while the loop is open
            tick = term.condition(tick)
        self._feedback_offset_K = tick.flange_K - tick.flange_feedback_K
        if self.mode is RegulatorMode.MANUAL:
            if self.modulation is not None:
                return RegulatorStep(self.modulation.power_w(time_s), math.nan, False, {})
            return RegulatorStep(self.manual_power_w, math.nan, False, {})
        if self.mode is RegulatorMode.OFF:
            return RegulatorStep(0.0, math.nan, False, {})
        tick = tick.with_setpoint(self.ramp.advance(dt_s))
        setpoint = tick.setpoint_K
        zones = self.control.zones
        if zones is not None and zones.index_for(setpoint) != self.zone_index:
            self._enter_zone(zones, zones.index_for(setpoint), f"setpoint in use {setpoint:.6g} K")
        # feedback terms first, held within the heater's range and told so (their anti-windup);
        # then the terms that ride on them (the feedforward's waveform), held again
        requested = 0.0
        for term in self._feedback:
            requested += term.update(tick)
        applied = min(max(requested, 0.0), self.maximum)
        for term in self._feedback:
            term.limit(requested, applied)
        limited = applied != requested
        if self._riding:
            requested = applied
            for term in self._riding:
                requested += term.update(tick)
            applied = min(max(requested, 0.0), self.maximum)
            for term in self._riding:
                term.limit(requested, applied)
            limited = limited or applied != requested
        columns: dict[str, float] = {}
        for term, names in self._column_names:
            columns.update(zip(names, term.column_values()))
        events: tuple[tuple[str, int, str], ...] = ()
        for term in self.terms:
            said = term.take_events()
            if said:
                events += tuple((term.name, level, text) for level, text in said)
        return RegulatorStep(self.output.power_w(applied), setpoint, limited, columns, events)

    # -- modes -------------------------------------------------------------------------
    def close_loop(self, time_s: float, flange_K: float, ptc_stage_K: float, present_power_w: float) -> None:
        """Regulate from now on, continuing from ``present_power_w`` without a bump.

        With a ramp the setpoint starts at the present temperature and ramps to
        the target; without, it steps to the target and acts through the terms.
        """
        feedback_K = flange_K - self._feedback_offset_K      # T2 as the feedback terms see it
        self.ramp.setpoint_K = feedback_K if self.ramp.rate_K_per_min > 0.0 else self.ramp.target_K
        zones = self.control.zones
        if zones is not None and zones.index_for(self.ramp.setpoint_K) != self.zone_index:
            self._enter_zone(zones, zones.index_for(self.ramp.setpoint_K),
                             f"loop closed at {self.ramp.setpoint_K:.6g} K")
        tick = TickInputs.at(time_s, 0.0, flange_K, ptc_stage_K, self.ramp.setpoint_K).with_feedback(feedback_K)
        present = self.output.output_for(present_power_w)
        for term in self.terms:
            term.start(tick, present)
        self.mode = RegulatorMode.CLOSED
        self.regulating = True

    def set_manual(self, power_w: float) -> None:
        """Open loop at ``power_w`` (W) until the loop is closed again; refused outside the heater's range."""
        if not 0.0 <= power_w <= self.output.max_power_w:
            raise ValueError(f"heater power {power_w:g} W refused: outside 0..{self.output.max_power_w:g} W "
                             f"(R * I_max^2)")
        self.manual_power_w = float(power_w)
        self.modulation = None
        self.mode = RegulatorMode.MANUAL
        self.regulating = False

    def set_modulated(self, modulation: "HeaterModulation") -> None:
        """Open loop with the heater following ``modulation`` (its phase counted from the next step);
        refused when it leaves the heater's range."""
        low, high = modulation.mean_w - modulation.amplitude_w, modulation.mean_w + modulation.amplitude_w
        if not (0.0 <= low and high <= self.output.max_power_w):
            raise ValueError(f"heater modulation {modulation.mean_w:g} +- {modulation.amplitude_w:g} W refused: "
                             f"outside 0..{self.output.max_power_w:g} W (R * I_max^2)")
        self.manual_power_w = modulation.mean_w
        self.modulation = HeaterModulation(modulation.mean_w, modulation.amplitude_w,
                                           modulation.angular_frequency_rad_s)
        self.mode = RegulatorMode.MANUAL
        self.regulating = False

    def close(self) -> None:
        """Release what the terms hold (the feedforward's learning thread)."""
        for term in self.terms:
            term.close()

    def follow_timing(self, on_time: bool) -> None:
        """Tell every term whether the loop's cycles keep their deadlines (:meth:`ControlTerm.follow_timing`)."""
        for term in self.terms:
            term.follow_timing(on_time)

    def term(self, name: str) -> ControlTerm | None:
        """The control term called ``name``, if this regulator has it."""
        return next((term for term in self.terms if term.name == name), None)

    def switch_off(self) -> None:
        """Heater at 0 W until the loop is closed again."""
        self.manual_power_w = 0.0
        self.modulation = None
        self.mode = RegulatorMode.OFF
        self.regulating = False

    # -- configuration -------------------------------------------------------------------
    def refusal(self, control: ControlConfig) -> tuple[str, str] | None:
        """Why ``control`` cannot be applied now: (the key it breaks, the reason), or None.

        In every mode the ramp rate that would be in use must be within the new
        ``max_ramp_K_per_min`` (a rate set by command outlives a heater-off). While the mode is
        closed, the setpoint aimed at, and once regulating the setpoint in use (where a ramp has
        got to; with steps, the target from the next tick on), must be within the new
        ``setpoint_min_K..setpoint_max_K``. In manual and off no setpoint is in use: the next
        ``setpoint`` command is checked against the new limits.
        """
        names = [name for name, _ in control.terms]
        if names != [term.name for term in self.terms]:
            return "control", f"the control terms would change ({', '.join(names)}): that needs a restart"
        rate, target = self._rate_and_target(control)
        if rate > control.max_ramp_K_per_min:
            return ("control.max_ramp_K_per_min",
                    f"{control.max_ramp_K_per_min:g} K/min is below the ramp rate in use, {rate:g} K/min (set with "
                    f"cryod ctl ramp): set a slower ramp first")
        if self.mode is not RegulatorMode.CLOSED:
            return None
        in_use = self.ramp.setpoint_K if self.regulating and rate > 0.0 else target
        aimed = "the setpoint in use" if self.regulating else "the setpoint asked for"
        setpoints = [(target, f"{aimed}, {target:g} K", "give a setpoint within the new limits first")]
        if in_use != target:
            setpoints.insert(0, (in_use, f"the setpoint in use, {in_use:.6g} K, ramping to {target:g} K at {rate:g} "
                                         f"K/min", "reload once the ramp has passed it, or step to the target "
                                                   "first (cryod ctl ramp 0)"))
        for value, what, advice in setpoints:
            if value > control.setpoint_max_K:
                return ("control.setpoint_max_K",
                        f"{control.setpoint_max_K:g} K is below {what}: {advice}")
            if value < control.setpoint_min_K:
                return ("control.setpoint_min_K",
                        f"{control.setpoint_min_K:g} K is above {what}: {advice}")
        return None

    def reconfigure(self, control: ControlConfig) -> None:
        """Apply a reloaded ``control`` section bumplessly (check :meth:`refusal` first).

        A setpoint or ramp rate that the reload changed replaces the one in use;
        one it left as it was keeps what commands set since.
        """
        self.ramp.rate_K_per_min, self.ramp.target_K = self._rate_and_target(control)
        previous, self.control = self.control.zones, control
        if control.zones is None:
            self.maximum = self.output.maximum
            if self.zone_index is not None:
                self._zone_events.append("no zones (reload): control.pi and control.feedforward at every temperature")
            self.zone_index = None
            settings = dict(control.terms)
            for term in self.terms:
                term.reconfigure(settings[term.name], self.maximum)
            return
        index = control.zones.index_for(self.ramp.setpoint_K)
        changed = previous is None or self.zone_index is None or previous.zones[self.zone_index] \
            != control.zones.zones[index] or index != self.zone_index
        reason = f"reload of {control.zones.source or 'the zone table'}" if changed else ""
        self._enter_zone(control.zones, index, reason, setpoint_moved=False)

    # -- zones ---------------------------------------------------------------------------
    def _enter_zone(self, zones: ZoneTable, index: int, reason: str, setpoint_moved: bool = True) -> None:
        """Run on zone ``index`` of ``zones`` (``control.zones``) from now on, bumplessly: every term takes the zone's
        settings through its ``reconfigure`` (the PI keeps its output, its integral taking the difference of
        the gains), and the terms' sum is held within the zone's heater limit. ``reason`` ('' for none) goes
        into the zone's event. When the setpoint in use moved from another zone into this one (not at the
        start, not on a reload), every term is then told (``enter_zone``): the cryostat is at another
        operating point, and what a term learned of it at the previous one (the feedforward's plant) is
        the term's to drop."""
        zone = zones.zones[index]
        limit = zone.max_heater_power_W
        self.maximum = self.output.maximum if limit is None else min(self.output.maximum,
                                                                     self.output.output_for(limit))
        settings = dict(self.control.terms)
        for term in self.terms:
            term.reconfigure(zone.settings_for(term.name, settings[term.name]), self.maximum)
        if setpoint_moved and self.zone_index is not None and index != self.zone_index:
            for term in self.terms:
                term.enter_zone(index)
        self.zone_index = index
        if reason:
            self._zone_events.append(f"{zone.describe(index)}; {reason}")

    def zone_events(self) -> list[str]:
        """What changed of the zone in use since the last call (one text each; the loop records them)."""
        events, self._zone_events = self._zone_events, []
        return events

    @property
    def zone(self):
        """The zone in use (:class:`cryod.control.zones.Zone`), None without zones."""
        return None if self.zone_index is None else self.control.zones.zones[self.zone_index]

    def _rate_and_target(self, control: ControlConfig) -> tuple[float, float]:
        previous = self.control
        rate = control.ramp_K_per_min if control.ramp_K_per_min != previous.ramp_K_per_min \
            else self.ramp.rate_K_per_min
        target_K = self.ramp.target_K
        if control.setpoint_K is not None and control.setpoint_K != previous.setpoint_K:
            target_K = control.setpoint_K
        return rate, target_K
