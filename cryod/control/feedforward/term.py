"""The ``feedforward`` control term: a heater waveform locked to the cooler that cancels its line on the flange.

PI cannot remove the pulse-tube cooler's line from T2: at 10.8 rad/s the heater
reaches T2 only through G2*G1, about 7 mK/W lagging 90 degrees. The cooler's
oscillation in T5 gives its phase, and the heater plays a waveform locked to
that phase whose effect on T2 cancels the line. docs/explanation/feedforward.md says how
and why, with the equations and the results ("How it works", "Learning the
cryostat it is on"); here, where each part lives. Every tick the term

1. tracks the cooler's phase from T5 (:mod:`cryod.cooler.phase`);
2. estimates T2's part synchronous with the cooler, split into the line and
   the waveform's effect (the learner, a Kalman filter:
   :mod:`cryod.control.feedforward.synchronous_estimator`, fed on a worker
   thread: :mod:`cryod.control.feedforward.learning_worker`, with the readings
   of :mod:`cryod.control.feedforward.reading_feed`), and gives the feedback
   terms T2 without it, so PI does not chase the line;
3. plays the waveform ``Re(sum_n u_n exp(j n phase))`` (no mean, harmonics 1
   to N) at the phase of the middle of the coming hold
   (:mod:`cryod.control.feedforward.played_waveform`), riding on PI's power
   (:mod:`cryod.control.feedforward.power_levels`), its effect measured in
   the plant as the loop samples it
   (:mod:`cryod.control.feedforward.harmonic_plant`) and as learned
   (:mod:`cryod.control.feedforward.plant_learner`, with a small probe where
   the waveform's own changes do not tell it:
   :mod:`cryod.control.feedforward.plant_probe`);
4. every ``update_interval_s``, steps the waveform toward cancelling the line
   and projects it onto what the heater can play
   (:mod:`cryod.control.feedforward.learning_step`, on the worker;
   :mod:`cryod.control.feedforward.learning_steps`, on the loop's thread),
   under a guard that steps back from a learning that makes T2 worse
   (:mod:`cryod.control.feedforward.divergence_guard`);
5. moves between its states (:mod:`cryod.control.feedforward.state_machine`,
   one table): the waveform fades in once the cooler's phase is locked, and
   out when switched off, without the lock, while the loop's cycles are late
   and after a divergence, when learning waits before it starts again
   (:mod:`cryod.control.feedforward.divergence_retry`).

The term rides on the feedback (``rides_on_feedback``): the regulator adds it
after PI's sum has been held within the heater's range, so a clipped waveform
never stops PI integrating; what the heater could not play is followed by
:mod:`cryod.control.feedforward.unplayed_power`. The physical limit at the
setpoint in use comes from :mod:`cryod.control.feedforward.limit_follower`;
what the learning finds goes to the journal and the record through
:mod:`cryod.control.feedforward.learning_report`; its record columns are
:mod:`cryod.control.feedforward.record_columns`, the words of
``cryod ctl feedforward status`` :mod:`cryod.control.feedforward.status_text`.

Its configuration, the section ``control.feedforward``: :mod:`cryod.control.feedforward.settings`.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

from cryod.control.feedforward.harmonic_plant import plant_at_harmonics
from cryod.control.feedforward.learned_limit import LearnedLimitInputs
from cryod.control.feedforward.learning_steps import LearningSteps
from cryod.control.feedforward.limit_follower import LimitFollower
from cryod.control.feedforward.plant_learner import LearnedPlant
from cryod.control.feedforward.plant_probe import ProbeState
from cryod.control.feedforward.played_waveform import PlayedWaveform, faded, harmonic_sum
from cryod.control.feedforward.power_levels import PowerLevels
from cryod.control.feedforward.reading_feed import ReadingFeed
from cryod.control.feedforward.record_columns import COLUMNS
from cryod.control.feedforward.settings import FeedforwardSettings, settings_from
from cryod.control.feedforward.state_machine import (BEHAVIOURS, FeedforwardEvent, FeedforwardState, next_state,
                                                     verdict)
from cryod.control.feedforward.status_text import FeedforwardStatus, status_text
from cryod.control.feedforward.synchronous_estimator import SynchronousEstimator
from cryod.control.feedforward.unplayed_power import UnplayedPower
from cryod.control.terms import ControlTerm, TickInputs
from cryod.cooler.phase import CoolerPhaseTracker

#: The plant response is recomputed when the delay from T2's sample to the heater setting moves by more (s).
SETTING_DELAY_TOLERANCE_S = 0.002


class FeedforwardTerm(ControlTerm):
    """The ``feedforward`` control term (module notes)."""

    name = "feedforward"
    required = False
    rides_on_feedback = True
    columns = COLUMNS

    def __init__(self, settings: FeedforwardSettings, output_max: float):
        self.output_max = output_max
        self.switched_on = settings.enabled
        self.on_time = True                 # the loop's cycles keep their deadlines (follow_timing)
        #: Where the feedforward is (:mod:`cryod.control.feedforward.state_machine`).
        self.state = FeedforwardState.WAITING_FOR_LOCK if settings.enabled else FeedforwardState.OFF
        self.scale = 0.0                    # the fade: 0 (out) to 1 (full)
        self.waveform = PlayedWaveform(settings.harmonics)
        self.steps = LearningSteps(settings.harmonics)
        self.readings = ReadingFeed()
        self.levels = PowerLevels()
        #: The plant at each harmonic as the loop samples it (K/W), from the controller's model.
        self.plant: np.ndarray | None = None
        self.tracker: CoolerPhaseTracker | None = None
        self.phase = None                   # the cooler's phase at this tick (None: not tracked)
        self.setting_delay_s = 0.0
        self.output_w = 0.0
        self.time_s = 0.0                   # the last closed-loop tick's
        self._flange_phase_rad = math.nan
        self._updated = False               # update() ran last tick: the heater played the waveform
        self._output_time_s = 0.0           # when this tick's power takes effect
        self.limits: LimitFollower | None = None        # the physical limit at the setpoint in use
        self._configure(settings)

    settings_from = staticmethod(settings_from)     # the control.feedforward section, validated (settings.py)

    def _configure(self, settings: FeedforwardSettings) -> None:
        self.settings = settings
        model = settings.controller_model
        harmonics = settings.harmonics
        if self.tracker is None or self.tracker.nominal_rad_s != model.ptc.angular_frequency_rad_s \
                or self.tracker.minimum_amplitude_K != settings.minimum_cooler_amplitude_K:
            self.tracker = CoolerPhaseTracker(model.ptc.angular_frequency_rad_s,
                                              minimum_amplitude_K=settings.minimum_cooler_amplitude_K)
        if self.limits is None:
            self.limits = LimitFollower(model)
        self.limits.use_model(model)
        self.readings.unplayed = UnplayedPower(model)
        previous_plant = self.plant
        self.plant = plant_at_harmonics(model, np.arange(1, harmonics + 1), settings.period_s, self.setting_delay_s)
        if self.waveform.coefficients.size != harmonics:            # keep what was learned, as far as it goes
            self.waveform.resize(harmonics)
            self.steps.probe_state = ProbeState.start(harmonics)
        if self.steps.needs_estimator(harmonics, settings.memory_s):
            self._take_step()
            self.steps.use_estimator(SynchronousEstimator(harmonics, model.sensor_noise.flange_thermometer_rms_K,
                                                          settings.memory_s, settings.period_s), self.plant)
        else:
            self.steps.keep_learned_plant(previous_plant, self.plant)

    def reconfigure(self, settings: FeedforwardSettings, output_max: float) -> None:
        """A reload: new settings, keeping the lock, the learned plant and the learned waveform (bumpless)."""
        self.output_max = output_max
        if settings.enabled != self.settings.enabled:
            self.switched_on = settings.enabled
        self._configure(settings)

    def close(self) -> None:
        """End the learning thread and the limit's (the regulator closes its terms when the loop stops)."""
        self.steps.close()
        self.limits.close()

    # -- what the operator and the loop say ---------------------------------------------
    def switch(self, on: bool) -> None:
        """``cryod ctl feedforward on|off``: fade in or out."""
        self.switched_on = bool(on)

    def follow_timing(self, on_time: bool) -> None:
        """Late cycles in a row put the waveform's phase and the learning's inputs in doubt: the waveform fades
        out and learning pauses until the cycles keep their deadlines again, then it fades back in."""
        self.on_time = bool(on_time)

    def enter_zone(self, index: int) -> None:
        """The setpoint in use moved into zone ``index`` (from 0), whose model :meth:`reconfigure` has just taken:
        another operating point, so the learned plant starts again from that model with the prior's spread (the
        probe, the learned limit and PI alone's line too); the waveform plays on, no bump. Said as an event."""
        self._take_step()               # a step computed at the previous operating point is taken first
        self.steps.zone_entered(index, self.settings, self.plant)
        self.limits.forget_learned()
        self._move(FeedforwardEvent.PLANT_FORGOTTEN)

    def _move(self, event: FeedforwardEvent) -> FeedforwardState:
        """Take ``event`` (:func:`~cryod.control.feedforward.state_machine.next_state`); the state left."""
        left, self.state = self.state, next_state(self.state, event)
        return left

    # -- the cycle ---------------------------------------------------------------------
    def condition(self, tick: TickInputs) -> TickInputs:
        """Track the cooler from T5, hand T2's reading to the estimator, and give the following terms
        T2 without its estimated synchronous part (PI must not chase the line)."""
        # the step asked for last tick, before this reading goes in: the readings from here on are the
        # new waveform's (applied later, T2's transient at the change would be taken for the plant's answer)
        self._take_step()
        if not self._updated:                   # the loop was open last tick: no waveform reached the heater
            self.waveform.scale_played = 0.0
        self._updated = False
        worker = self.steps.worker
        if not (self.switched_on or self.scale > 0.0):
            # off: PI alone, as without this term, at no cost to the loop (the cooler is not even tracked;
            # switched on, it locks again within seconds)
            if self.phase is not None:
                self.readings.gap(worker)
                self.tracker.reset()
                self.phase = None
            return tick
        phase = self.phase = self.tracker.update(tick.ptc_stage_time_s, tick.ptc_stage_K)
        self._follow_setting_delay(tick.output_time_s - tick.flange_time_s)
        flange_phase = self._flange_phase_rad = phase.phase_at(tick.flange_time_s)
        if not phase.locked:
            self.readings.gap(worker)
            return tick
        effect = self.waveform.effect(self.plant)
        self.readings.take(worker, tick, phase, flange_phase, effect, self.settings.period_s)
        if not self.steps.estimate.ready:
            return tick
        # PI sees T2 without its synchronous part, as much of it as the waveform has faded in
        value = harmonic_sum(self.steps.synchronous(effect), cmath.exp(1j * flange_phase))
        return tick.with_feedback(tick.flange_feedback_K - self.scale * value)

    def _follow_setting_delay(self, delay_s: float) -> None:
        """The plant response depends on how long after T2's sample the heater is set: follow it."""
        delay_s = min(max(delay_s, 0.0), 0.99 * self.settings.period_s)
        if abs(delay_s - self.setting_delay_s) > SETTING_DELAY_TOLERANCE_S:
            self.setting_delay_s = delay_s
            self.plant = plant_at_harmonics(self.settings.controller_model, np.arange(1, self.settings.harmonics + 1),
                                            self.settings.period_s, delay_s)

    def start(self, tick: TickInputs, present_output: float) -> None:
        self.scale = 0.0            # the waveform fades in: closing the loop stays bumpless
        self._move(FeedforwardEvent.LOOP_CLOSED)

    def update(self, tick: TickInputs) -> float:
        self._updated = True
        self._output_time_s = tick.output_time_s
        self.time_s = tick.time_s
        locked = self.phase is not None and self.phase.locked
        self._move(verdict(self.switched_on, self.on_time, locked, self.steps.retry.pending(tick.time_s)))
        plays = BEHAVIOURS[self.state].plays
        self.scale = faded(self.scale, 1.0 if plays else 0.0, tick.dt_s, self.settings.fade_time_s)
        if plays and self.scale >= 1.0:
            self._move(FeedforwardEvent.FADED_IN)
        elif not plays and self.scale <= 0.0:
            if self._move(FeedforwardEvent.FADED_OUT) is FeedforwardState.DIVERGED:
                self._start_again_later()
        if locked and (self.switched_on or self.scale > 0.0) and self.steps.due(tick.time_s,
                                                                                 self.settings.update_interval_s):
            self.levels.follow_mean(abs(tick.setpoint_K - tick.flange_feedback_K), self.settings.update_interval_s)
            self.steps.ask(self.settings, self.plant, self.waveform, self.levels, self.output_max,
                           self.phase.frequency_rad_s, moves=plays)
        self.limits.follow(tick.time_s, tick.setpoint_K, self.output_max, self.settings.period_s,
                           self.setting_delay_s, self._learned_limit_inputs)
        if self.scale <= 0.0 or self.phase is None:
            self.output_w = self.waveform.scale_played = 0.0
            return 0.0
        rotor = cmath.exp(1j * self.phase.phase_at(tick.output_time_s + 0.5 * self.settings.period_s))  # mid-hold
        value, change_K = self.waveform.play(rotor, self.phase.frequency_rad_s * self.settings.period_s, self.plant,
                                             self.scale)
        self.readings.heater_changed(tick.output_time_s, change_K)
        self.output_w = self.scale * value
        return self.output_w

    def limit(self, requested: float, applied: float) -> None:
        self.levels.follow_others(requested - self.output_w, self.settings.period_s)
        self.readings.unplayed.set(self._output_time_s, applied - requested)

    # -- learning (the worker computes, the loop takes the result at the next tick) ---------
    def _take_step(self) -> None:
        """Apply the step asked for last tick (waiting for the worker if it is behind), and move on what it found."""
        cooler_K = self.phase.amplitude_K if self.phase is not None else math.nan
        for event in self.steps.take(self.waveform, BEHAVIOURS[self.state].guard_watches, cooler_K, self.time_s,
                                     self.settings.retry_after_s, self.levels.settled):
            self._move(event)

    def _start_again_later(self) -> None:
        """The waveform is out after a divergence: nothing played, the model's plant again, learning later."""
        self.steps.retry.faded_out(self.time_s, self.settings.retry_after_s)
        self.waveform.clear()
        self.steps.forget_plant(self.settings.harmonics, self.plant)
        self.limits.forget_learned()

    def _learned_limit_inputs(self, setpoint_K: float) -> LearnedLimitInputs | None:
        return self.steps.learned_limit_inputs(self.levels, self.time_s, setpoint_K, self.output_max,
                                               self.settings.period_s, self.setting_delay_s)

    # -- what it shows -------------------------------------------------------------------
    def take_events(self) -> tuple[tuple[int, str], ...]:
        """What the learning found since the last tick: (logging level, text) pairs for the journal and the data log."""
        return self.steps.report.take()

    def column_values(self) -> tuple[float, ...]:
        phase, probe = self.phase, self.steps.probe_column
        limit, authority, source = self.limits.columns
        if phase is None:
            return self.output_w, math.nan, math.nan, 0.0, math.nan, self.scale, limit, authority, source, probe
        return (self.output_w, self._flange_phase_rad, phase.frequency_rad_s, 1.0 if phase.locked else 0.0,
                self.steps.estimate.line_amplitude_K, self.scale, limit, authority, source, probe)

    @property
    def phase_locked(self) -> bool:
        """Whether the cooler's phase is tracked and locked now (the waveform plays only then)."""
        return self.phase is not None and self.phase.locked

    @property
    def coefficients(self) -> np.ndarray:
        """The waveform's complex amplitudes ``u_n`` (W), n = 1..harmonics (the probe not included)."""
        return self.waveform.coefficients

    @property
    def probe(self) -> np.ndarray:
        """The probe's complex amplitudes (W) per harmonic, played with the waveform."""
        return self.waveform.probe

    @property
    def learned_plant(self) -> LearnedPlant:
        """The plant as the last learning step knew it."""
        return self.steps.estimate.learned

    @property
    def divergences(self) -> int:
        """Learning divergences since the start."""
        return self.steps.retry.count

    @property
    def physical_limit(self):
        """The physical limit at the setpoint in use (:mod:`cryod.control.feedforward.limit`): from what was
        learned once it is, else from the model; None until the setpoint has been steady a few seconds."""
        return self.limits.limit

    def status_snapshot(self) -> FeedforwardStatus:
        """What ``cryod ctl feedforward status`` says, as values taken now (words: ``status_text``)."""
        return FeedforwardStatus.of(self)

    def describe(self) -> str:
        """The feedforward's state in a few lines (``cryod ctl feedforward status``; the daemon words it elsewhere)."""
        return status_text(self.status_snapshot())

    def learning_summary(self) -> dict:
        """What was learned, for ``--json``: the plant per harmonic, the limit reported and where it came from."""
        return self.steps.summary(self.limits, self.setting_delay_s)
