"""The ``feedforward`` control term: a heater waveform locked to the cooler that cancels its line on the flange.

PI cannot remove the pulse-tube cooler's line from T2: at 10.8 rad/s the heater
reaches T2 only through G2*G1, about 7 mK/W lagging 90 degrees. The cooler's
oscillation in T5 gives its phase, and the heater plays a waveform locked to
that phase whose effect on T2 cancels the line. docs/feedforward.md says how
and why, with the equations and the results ("How it works", "Learning the
cryostat it is on"); here, where each part lives. Every tick the term

1. tracks the cooler's phase from T5 (:mod:`cryod.cooler.phase`);
2. estimates T2's part synchronous with the cooler, split into the line and
   the waveform's effect (the learner, a Kalman filter:
   :mod:`cryod.control.feedforward.synchronous_estimator`, fed on a worker
   thread: :mod:`cryod.control.feedforward.learning_worker`), and gives the
   feedback terms T2 without it, so PI does not chase the line;
3. plays the waveform ``Re(sum_n u_n exp(j n phase))`` (no mean, harmonics 1
   to N) at the phase of the middle of the coming hold, its effect measured in
   the plant as the loop samples it
   (:mod:`cryod.control.feedforward.harmonic_plant`) and as learned
   (:mod:`cryod.control.feedforward.plant_learner`, with a small probe where
   the waveform's own changes do not tell it:
   :mod:`cryod.control.feedforward.plant_probe`);
4. every ``update_interval_s``, steps the waveform toward cancelling the line
   and projects it onto what the heater can play
   (:mod:`cryod.control.feedforward.learned_projection`), under a guard that
   steps back from a learning that makes T2 worse
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
:mod:`cryod.control.feedforward.learning_report`.

Its configuration, the section ``control.feedforward``: :mod:`cryod.control.feedforward.settings`.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import replace

import numpy as np

from cryod.control.feedforward.divergence_guard import DivergenceGuard
from cryod.control.feedforward.divergence_retry import DivergenceRetry
from cryod.control.feedforward.learning_worker import LearningWorker
from cryod.control.feedforward.harmonic_plant import plant_at_harmonics
from cryod.control.feedforward.learned_limit import LearnedLimitInputs
from cryod.control.feedforward.learning_step import LearningStep, StepResult
from cryod.control.feedforward.learning_report import LearningReport
from cryod.control.feedforward.limit_follower import LimitFollower
from cryod.control.feedforward.plant_learner import LearnedPlant
from cryod.control.feedforward.settings import FeedforwardSettings, settings_from
from cryod.control.feedforward.plant_probe import ProbeState
from cryod.control.feedforward.status_text import FeedforwardStatus, read_only, status_text
from cryod.control.feedforward.state_machine import BEHAVIOURS, FeedforwardEvent, FeedforwardState, next_state, verdict
from cryod.control.feedforward.synchronous_estimator import SynchronousEstimator
from cryod.control.terms import ControlTerm, TickInputs
from cryod.control.feedforward.unplayed_power import UnplayedPower
from cryod.cooler.phase import CoolerPhaseTracker
from cryod.records.columns import Column
from cryod.yaml_source import Section

#: After a gap in the loop (a fault, start-up), T2's readings are left out this long (s).
SETTLE_S = 1.0
#: After a change of what the heater plays (a learning step, the probe turning), T2's readings are left out this
#: long (s): a thermometer that lags or a heater that acts late answers the old waveform and the new one mixed for
#: a while, and taking those readings as the new one's answer would bias the plant learned by the change.
CHANGE_SETTLE_S = 0.5
#: ... when the change moves T2 by more than this (K, through the model's plant): a change of a few microkelvin (a
#: converged waveform following the line's noise) mixes nothing that matters against the readings' noise.
CHANGE_SETTLE_ABOVE_K = 20e-6
#: Smoothing of the feedback terms' power, the level the waveform rides on (s).
BASE_TIME_S = 2.0
#: The plant response is recomputed when the delay from T2's sample to the heater setting moves by more (s).
SETTING_DELAY_TOLERANCE_S = 0.002
#: Learning steps in a row that make a divergence (:class:`~cryod.control.feedforward.divergence_guard.DivergenceGuard`).
DIVERGENCE_STEPS = 5
#: Smoothing of PI's power for the mean power the setpoint needs (s), and of T2's distance from the setpoint.
MEAN_POWER_TIME_S = 60.0
SETTLING_TIME_S = 20.0
#: T2 is taken as settled at the setpoint (its mean power the one the setpoint needs) within this (K) ...
SETTLED_K = 2e-4
#: ... and as still on its way to it (the probe may be larger) beyond this (K).
APPROACHING_K = 2e-3
#: The learned limit needs the plant at the line known to this (relative standard deviation).
LIMIT_PLANT_SPREAD = 0.1


class FeedforwardTerm(ControlTerm):
    """The ``feedforward`` control term (module notes)."""

    name = "feedforward"
    required = False
    rides_on_feedback = True
    columns = (
        Column("ff_W", "W", "feedforward heater part (locked to the cooler)", "{:.6e}"),
        Column("ff_phase_rad", "rad", "cooler phase at the T2 reading (T5's fundamental is A cos(phase))",
               "{:.4f}"),
        Column("ff_frequency_rad_s", "rad/s", "cooler angular frequency tracked from T5", "{:.5f}"),
        Column("ff_locked", "", "1 when the phase tracker is locked to the cooler", "{:.0f}"),
        Column("ff_line_K", "K", "amplitude of T2's part synchronous with the cooler as estimated at the last "
                                 "learning step (sqrt of the sum of the harmonics' squared amplitudes)", "{:.4e}"),
        Column("ff_scale", "", "fade of the waveform, 0 (off) to 1 (on)", "{:.3f}"),
        Column("ff_limit_K", "K", "the physical limit at this setpoint: the least synchronous T2 any heater "
                                  "waveform can leave (feedforward-limit; empty until computed)", "{:.3e}"),
        Column("ff_authority", "", "largest fundamental the heater can give over the one the line needs "
                                   "(below 1: authority-limited)", "{:.3f}"),
        Column("ff_limit_from", "", "what ff_limit_K and ff_authority were computed from: model (the controller's "
                                    "model) or learned (the plant and line learned, the mean power PI found)"),
        Column("ff_probe_K", "K", "T2's answer to the probe (harmonics together), empty when it is off; the "
                                  "learned plant itself is in the record's feedforward events", "{:.2e}"),
    )

    def __init__(self, settings: FeedforwardSettings, output_max: float):
        self.output_max = output_max
        self.switched_on = settings.enabled
        #: The loop's cycles keep their deadlines (:meth:`follow_timing`): the waveform may play and learn.
        self.on_time = True
        self.scale = 0.0
        self._coefficients = np.zeros(settings.harmonics, dtype=complex)
        self._probe = np.zeros(settings.harmonics, dtype=complex)
        self._set_played()
        self._heard_coefficients = self._played_coefficients    # what the readings answer: nothing played yet
        #: The plant at each harmonic as the loop samples it (K/W), from the controller's model.
        self.plant: np.ndarray | None = None
        self.tracker: CoolerPhaseTracker | None = None
        self.worker: LearningWorker | None = None         # the estimator and the learning steps
        self._estimate: StepResult | None = None           # what the last learning step returned
        self._step_id = 0
        self._pending_step: int | None = None
        self.setting_delay_s = 0.0
        self.other_terms_w: float | None = None      # the feedback terms' power, smoothed
        self.mean_power_w: float | None = None       # ... smoothed over MEAN_POWER_TIME_S
        self._setpoint_distance_K = math.inf          # T2's distance from the setpoint, smoothed
        self.output_w = 0.0
        self.phase = None
        self._flange_phase_rad = math.nan
        self._applied_scale = 0.0           # the scale of the waveform the heater played last tick
        self._held_since_s = -math.inf      # when the loop last had a gap (the heater held off)
        self._changed_at_s = -math.inf      # when the heater began to play a new waveform or probe
        self._played = False                # update() ran last tick: the heater played the waveform
        self._output_time_s = 0.0           # when this tick's power takes effect
        self.unplayed: UnplayedPower | None = None      # the power held back at the heater's bounds
        self._next_update_s: float | None = None
        self._in_gap = False                # the worker was told of a gap since the last reading
        self._synchronous_cache = None
        self.probe_state: ProbeState = ProbeState.start(settings.harmonics)
        self.guard = DivergenceGuard(DIVERGENCE_STEPS)
        self.report = LearningReport()
        self._pi_alone: tuple[float, float] | None = None   # (line with no waveform played (K), T5's amplitude then)
        self.retry = DivergenceRetry()          # the divergences, and when learning may start again
        #: Where the feedforward is (:mod:`cryod.control.feedforward.state_machine`).
        self.state = FeedforwardState.WAITING_FOR_LOCK if settings.enabled else FeedforwardState.OFF
        self._time_s = 0.0
        self._probe_column = math.nan           # T2's answer to the probe being played (NaN: off)
        self._plant_known_for_limit = False     # the plant at the line known well enough for the learned limit
        #: The physical limit at the setpoint in use, from the model or from what was learned.
        self.limits: LimitFollower | None = None
        self._configure(settings)

    # -- configuration ---------------------------------------------------------------
    @staticmethod
    def settings_from(section: Section | None) -> FeedforwardSettings:
        """The ``control.feedforward`` section (defaults when absent: :mod:`~cryod.control.feedforward.settings`)."""
        return settings_from(section)

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
        self._orders = np.arange(1, harmonics + 1)
        self.unplayed = UnplayedPower(model)
        previous_plant = self.plant
        self.plant = plant_at_harmonics(model, self._orders, settings.period_s, self.setting_delay_s)
        self._effect_cache = None
        if self._coefficients.size != harmonics:                    # keep what was learned, as far as it goes
            self._coefficients, self._probe = _resized(self._coefficients, harmonics), _resized(self._probe, harmonics)
            self._set_played()
            self.probe_state = ProbeState.start(harmonics)
        worker = self.worker
        if worker is None or worker.estimator.harmonics != harmonics or worker.estimator.memory_s != settings.memory_s:
            if worker is not None:
                self._take_step_result()
                worker.close()
            self.worker = LearningWorker(SynchronousEstimator(harmonics, model.sensor_noise.flange_thermometer_rms_K,
                                                              settings.memory_s, settings.period_s))
            self._estimate = StepResult.empty(self.plant)
        elif previous_plant is not None and previous_plant.size == harmonics and \
                not np.allclose(previous_plant, self.plant, rtol=1e-12, atol=0.0):
            # another controller's model: the cryostat did not change, so neither does the plant learned
            factor = previous_plant / self.plant
            self.worker.apply(lambda estimator: estimator.rescale_correction(factor))

    def reconfigure(self, settings: FeedforwardSettings, output_max: float) -> None:
        """A reload: new settings, keeping the lock, the learned plant and the learned waveform (bumpless)."""
        self.output_max = output_max
        if settings.enabled != self.settings.enabled:
            self.switched_on = settings.enabled
        self._configure(settings)

    def close(self) -> None:
        """End the learning thread and the limit's (the regulator closes its terms when the loop stops)."""
        if self.worker is not None:
            self.worker.close()
        self.limits.close()

    def follow_timing(self, on_time: bool) -> None:
        """Late cycles in a row put the waveform's phase and the learning's inputs in doubt: the waveform fades
        out and learning pauses until the cycles keep their deadlines again, then it fades back in."""
        self.on_time = bool(on_time)

    def switch(self, on: bool) -> None:
        """``cryod ctl feedforward on|off``: fade in or out."""
        self.switched_on = bool(on)

    @property
    def phase_locked(self) -> bool:
        """Whether the cooler's phase is tracked and locked now (the waveform plays only then)."""
        return self.phase is not None and self.phase.locked

    # -- the cycle ---------------------------------------------------------------------
    def condition(self, tick: TickInputs) -> TickInputs:
        """Track the cooler from T5, hand T2's reading to the estimator, and give the following terms
        T2 without its estimated synchronous part (PI must not chase the line)."""
        # the step asked for last tick, before this reading goes in: the readings from here on are the
        # new waveform's (applied later, T2's transient at the change would be taken for the plant's answer)
        self._take_step_result()
        if not self._played:                    # the loop was open last tick: no waveform reached the heater
            self._applied_scale = 0.0
        self._played = False
        if not (self.switched_on or self.scale > 0.0):
            # off: PI alone, as without this term, at no cost to the loop (the cooler is not even tracked;
            # switched on, it locks again within seconds)
            if self.phase is not None:
                self._gap()
                self.tracker.reset()
                self.phase = None
            return tick
        phase = self.phase = self.tracker.update(tick.ptc_stage_time_s, tick.ptc_stage_K)
        self._follow_setting_delay(tick.output_time_s - tick.flange_time_s)
        flange_phase = self._flange_phase_rad = phase.phase_at(tick.flange_time_s)
        if not phase.locked:
            self._gap()
            return tick
        effect = self._effect()
        if tick.dt_s > 1.5 * self.settings.period_s:
            self._held_since_s = phase.time_s       # a gap: the loop held the heater off (a fault, start-up)
            self.unplayed.reset()
        if phase.time_s - self._held_since_s < SETTLE_S or tick.flange_time_s - self._changed_at_s < CHANGE_SETTLE_S:
            # after a gap the heater did not play the waveform the estimator assumes, and after a change it played
            # the old and the new: wait until T2 has settled
            self._gap()
        else:
            self._in_gap = False
            # where the total was held at a bound, T2 as if the heater had played what was asked
            self.worker.reading(flange_phase, tick.flange_K - self.unplayed.at(tick.flange_time_s), effect)
        if not self._estimate.ready:
            return tick
        # PI sees T2 without its synchronous part, as much of it as the waveform has faded in
        rotor = cmath.exp(1j * flange_phase)
        value, power = 0.0, 1.0 + 0j
        for phasor in self._synchronous_list():
            power *= rotor
            value += (phasor * power).real
        return tick.with_feedback(tick.flange_feedback_K - self.scale * value)

    def _gap(self) -> None:
        if not self._in_gap:
            self._in_gap = True
            self.worker.gap()

    def _synchronous_list(self) -> list[complex]:
        """``L_n + k_n z_n`` of the last step's estimate for the waveform now, as plain complex (cached)."""
        effect = self._effect()
        cache = self._synchronous_cache
        if cache is None or cache[0] is not self._estimate or cache[1] is not effect:
            phasors = self._estimate.line + self._estimate.learned.correction * effect
            cache = self._synchronous_cache = (self._estimate, effect, [complex(value) for value in phasors])
        return cache[2]

    def _follow_setting_delay(self, delay_s: float) -> None:
        """The plant response depends on how long after T2's sample the heater is set: follow it."""
        delay_s = min(max(delay_s, 0.0), 0.99 * self.settings.period_s)
        if abs(delay_s - self.setting_delay_s) > SETTING_DELAY_TOLERANCE_S:
            self.setting_delay_s = delay_s
            self._effect_cache = None
            self.plant = plant_at_harmonics(self.settings.controller_model, self._orders, self.settings.period_s,
                                            delay_s)

    def start(self, tick: TickInputs, present_output: float) -> None:
        self.scale = 0.0            # the waveform fades in: closing the loop stays bumpless
        self._move(FeedforwardEvent.LOOP_CLOSED)

    def _move(self, event: FeedforwardEvent) -> FeedforwardState:
        """Take ``event`` (:func:`~cryod.control.feedforward.state_machine.next_state`); the state left."""
        left, self.state = self.state, next_state(self.state, event)
        return left

    def update(self, tick: TickInputs) -> float:
        self._played = True
        self._output_time_s = tick.output_time_s
        self._time_s = tick.time_s
        locked = self.phase is not None and self.phase.locked
        self._move(verdict(self.switched_on, self.on_time, locked, self.retry.pending(tick.time_s)))
        plays = BEHAVIOURS[self.state].plays
        wanted = 1.0 if plays else 0.0
        fade = self.settings.fade_time_s
        step = tick.dt_s / fade if fade > 0.0 else 1.0
        self.scale = min(self.scale + step, wanted) if wanted > self.scale else max(self.scale - step, wanted)
        if plays and self.scale >= 1.0:
            self._move(FeedforwardEvent.FADED_IN)
        elif not plays and self.scale <= 0.0:
            if self._move(FeedforwardEvent.FADED_OUT) is FeedforwardState.DIVERGED:
                self._reset_learning(tick.time_s)
        if locked and (self.switched_on or self.scale > 0.0):
            if self._next_update_s is None:
                self._next_update_s = tick.time_s + self.settings.update_interval_s
            elif tick.time_s >= self._next_update_s:
                self._next_update_s += self.settings.update_interval_s
                self._follow_mean(abs(tick.setpoint_K - tick.flange_feedback_K))
                self._ask_for_step(plays)
        self.limits.follow(tick.time_s, tick.setpoint_K, self.output_max, self.settings.period_s,
                           self.setting_delay_s, self._learned_limit_inputs)
        if self.scale <= 0.0 or self.phase is None:
            self.output_w = self._applied_scale = 0.0
            return 0.0
        phase = self.phase.phase_at(tick.output_time_s + 0.5 * self.settings.period_s)  # middle of the hold
        rotor = cmath.exp(1j * phase)
        value, power = 0.0, 1.0 + 0j
        for coefficient in self._coefficient_list:           # plain complex: a numpy scalar per term is slow
            power *= rotor
            value += (coefficient * power).real
        self._applied_scale = self.scale
        if self._heard_coefficients is not self._played_coefficients:
            value += self._energy_kept(rotor)
            change_K = float(np.sum(np.abs(self.plant * (self._played_coefficients - self._heard_coefficients))))
            if change_K > CHANGE_SETTLE_ABOVE_K:
                self._changed_at_s = tick.output_time_s
            self._heard_coefficients = self._played_coefficients    # what the next readings answer
        self.output_w = self.scale * value
        return self.output_w

    def _energy_kept(self, rotor: complex) -> float:
        """The power to add for one tick where the waveform changes, so that the energy it delivers goes on as
        if it had always been the new one (W).

        A held waveform ``Re sum_n u_n exp(j n phase_k)`` delivers, summed over the ticks, a bounded
        oscillation plus a constant; changing ``u`` at tick K moves that constant by
        ``T Re sum_n (u_n - u'_n) exp(j n phase_K) / (exp(j n omega T) - 1)``, which depends on where in the
        period the change falls: a kick of energy the flange integrates into T2's mean (a few microkelvin for
        a change of a milliwatt, every learning step, below 0.1 Hz). This gives it back."""
        advance = self.phase.frequency_rad_s * self.settings.period_s
        turn = cmath.exp(1j * advance)
        power, step, kept = 1.0 + 0j, 1.0 + 0j, 0.0
        for new, old in zip(self._played_coefficients, self._heard_coefficients):
            power *= rotor
            step *= turn
            kept += ((new - old) * power / (step - 1.0)).real
        return kept

    @property
    def coefficients(self) -> np.ndarray:
        """The waveform's complex amplitudes ``u_n`` (W), n = 1..harmonics (the probe not included)."""
        return self._coefficients

    @coefficients.setter
    def coefficients(self, values) -> None:
        self._coefficients = np.asarray(values, dtype=complex)
        self._set_played()

    @property
    def probe(self) -> np.ndarray:
        """The probe's complex amplitudes (W) per harmonic, played with the waveform."""
        return self._probe

    def _set_played(self) -> None:
        """What the heater plays from the next output on: the waveform and the probe."""
        self._played_coefficients = self._coefficients + self._probe
        self._coefficient_list = [complex(value) for value in self._played_coefficients]

    def _effect(self) -> np.ndarray:
        """What the heater played last tick through the model, its effect on T2 (K per harmonic): a new waveform
        taken at this tick's start is played from this tick's output on, and the reading now still answers the
        one before (attributing it the new one would bias the plant learned by the change)."""
        scale = self._applied_scale
        heard = self._heard_coefficients
        cache = self._effect_cache
        if cache is None or cache[0] != scale or cache[1] is not heard:
            cache = self._effect_cache = (scale, heard, self.plant * heard * scale)
        return cache[2]

    def limit(self, requested: float, applied: float) -> None:
        others = requested - self.output_w
        if self.other_terms_w is None:
            self.other_terms_w = others
        else:       # the other terms' power, smoothed over about 2 s: the level the waveform rides on
            self.other_terms_w += (others - self.other_terms_w) * min(self.settings.period_s / BASE_TIME_S, 1.0)
        self.unplayed.set(self._output_time_s, applied - requested)

    def _follow_mean(self, distance_K: float) -> None:
        """At every learning step: PI's mean power and T2's distance from the setpoint, smoothed (for the learned
        limit: T2 settled at the setpoint, and the mean power that holds it)."""
        interval = self.settings.update_interval_s
        if self.other_terms_w is not None:
            self.mean_power_w = self.other_terms_w if self.mean_power_w is None else \
                self.mean_power_w + (self.other_terms_w - self.mean_power_w) * min(interval / MEAN_POWER_TIME_S, 1.0)
        if not math.isfinite(self._setpoint_distance_K):
            self._setpoint_distance_K = distance_K
        elif math.isfinite(distance_K):
            self._setpoint_distance_K += (distance_K - self._setpoint_distance_K) * min(interval / SETTLING_TIME_S, 1.0)

    def take_events(self) -> tuple[tuple[int, str], ...]:
        """What the learning found since the last tick: (logging level, text) pairs for the journal and the data log."""
        return self.report.take()

    def column_values(self) -> tuple[float, ...]:
        phase = self.phase
        limit, authority, source = self.limits.columns
        if phase is None:
            return (self.output_w, math.nan, math.nan, 0.0, math.nan, self.scale, limit, authority, source,
                    self._probe_column)
        return (self.output_w, self._flange_phase_rad, phase.frequency_rad_s, 1.0 if phase.locked else 0.0,
                self._estimate.line_amplitude_K, self.scale, limit, authority, source, self._probe_column)

    @property
    def physical_limit(self):
        """The physical limit at the setpoint in use (:mod:`cryod.control.feedforward.limit`): from what was
        learned once it is, else from the model; None until the setpoint has been steady a few seconds."""
        return self.limits.limit

    @property
    def limit_changes(self) -> tuple:
        """The limit if the setpoint moved by 0.5 K either way, or R I_max^2 doubled (LimitChange)."""
        return self.limits.changes

    @property
    def learned_plant(self) -> LearnedPlant:
        """The plant as the last learning step knew it."""
        return self._estimate.learned

    def status_snapshot(self) -> FeedforwardStatus:
        """What ``cryod ctl feedforward status`` says, taken now: values, immutable objects and read-only copies
        (on the loop's thread; the words: :func:`~cryod.control.feedforward.status_text.status_text`)."""
        estimate, settings = self._estimate, self.settings
        return FeedforwardStatus(
            switched_on=self.switched_on, scale=self.scale, fade_time_s=settings.fade_time_s,
            harmonics=settings.harmonics, cooler=self.phase, line_amplitude_K=estimate.line_amplitude_K,
            synchronous_K=tuple(self._synchronous_list()), line_K=read_only(estimate.line),
            coefficients_W=read_only(self._coefficients), played_W=read_only(self._played_coefficients),
            base_W=self.other_terms_w or 0.0, margin_W=settings.margin_W, maximum_W=self.output_max,
            model_source=settings.model_source, plant=estimate.learned, probe_state=self.probe_state,
            probe_W=read_only(self._probe), probe_cost_K=estimate.probe_cost_K,
            plant_precision=settings.plant_precision, cycles_on_time=self.on_time, divergence=self.retry.reason,
            divergences=self.retry.count, retry_in_s=self.retry.learn_again_s - self._time_s,
            limit=self.limits.limit, limit_from=self.limits.source, limit_changes=self.limits.changes)

    def describe(self) -> str:
        """The feedforward's state in a few lines (``cryod ctl feedforward status``), put in words here: the daemon
        words :meth:`status_snapshot` off the loop's thread."""
        return status_text(self.status_snapshot())

    @property
    def divergences(self) -> int:
        """Learning divergences since the start."""
        return self.retry.count

    def line_amplitude_K(self) -> float:
        """T2's synchronous part as estimated at the last learning step (K; NaN before there is one)."""
        return self._estimate.line_amplitude_K

    def learning_summary(self) -> dict:
        """What was learned, for ``--json``: the plant per harmonic, the limit reported and where it came from."""
        limit = self.physical_limit
        return {"feedforward_plant": self.learned_plant.summary(),
                "feedforward_plant_differences": self.learned_plant.differences(),
                "feedforward_reported_limit_K": None if limit is None else limit.ptc_periodic_limit_K,
                "feedforward_reported_authority": None if limit is None else limit.authority,
                "feedforward_limit_from": self.limits.source,
                "feedforward_probe_K": self._estimate.probe_cost_K,
                "feedforward_divergences": self.divergences,
                "feedforward_setting_delay_s": self.setting_delay_s}

    # -- learning (the worker computes, the loop takes the result at the next tick) ---------
    def _ask_for_step(self, learning: bool) -> None:
        """Hand the worker what a learning step needs, as values, to compute after the readings so far."""
        if self.other_terms_w is None:
            return
        self._step_id += 1
        scale = self._applied_scale
        self.worker.step(self._step_id, LearningStep(
            plant=self.plant.copy(), coefficients=self._coefficients.copy(), effect=self._effect().copy(),
            waveform_effect=self.plant * self._coefficients * scale, learning=learning,
            gain=self.settings.learning_gain, base_w=self.other_terms_w, low_w=self.settings.margin_W,
            high_w=self.output_max - self.settings.margin_W, probe_state=self.probe_state,
            probe=self.settings.probe, interval_s=self.settings.update_interval_s,
            frequency_rad_s=self.phase.frequency_rad_s, before=self._estimate.learned,
            approaching=self._setpoint_distance_K > APPROACHING_K))
        self._pending_step = self._step_id

    def _take_step_result(self) -> None:
        """Apply the step asked for last tick (waiting for the worker if it is behind)."""
        if self._pending_step is None:
            return
        result = self.worker.result(self._pending_step)
        self._pending_step = None
        self._estimate = result
        plant = result.learned
        if result.coefficients is not None:      # a step that moves the waveform: asked while it played
            self._coefficients, self._probe = result.coefficients, result.probe
            self.probe_state = result.probe_state
            self._set_played()
            self._move(FeedforwardEvent.PROBE_PLAYS if np.any(self._probe) else
                       FeedforwardEvent.PLANT_KNOWN if plant.learned[0] else FeedforwardEvent.PLANT_UNKNOWN)
        playing = result.coefficients is not None and result.probe_cost_K > 0.0
        self._probe_column = result.probe_cost_K if playing else math.nan     # empty when off
        self._plant_known_for_limit = bool(plant.learned[0] and plant.relative_spread[0] < LIMIT_PLANT_SPREAD)
        if result.ready:
            self._judge(result)

    def _judge(self, result: "StepResult") -> None:
        """After a step: PI alone's line, the guard, what to report."""
        self.report.step(self._time_s, result.learned, self.probe_state.given_up())
        amplitude = self.phase.amplitude_K if self.phase is not None else math.nan
        if not np.any(self._coefficients):
            self._pi_alone = (float(np.sqrt(np.sum(np.abs(result.line) ** 2))), amplitude)
        if not BEHAVIOURS[self.state].guard_watches or not np.any(self._coefficients):
            self.guard.clear()
            return
        if self._pi_alone is not None and math.isfinite(amplitude) and self._pi_alone[1] > 0.0:
            pi_alone = self._pi_alone[0] * amplitude / self._pi_alone[1]
        else:
            pi_alone = float(np.sqrt(np.sum(np.abs(result.line) ** 2)))
        reason = self.guard.observe(result.residual_K, pi_alone)
        if reason is not None:
            self._move(FeedforwardEvent.DIVERGED)
            self.report.diverged(reason, self.retry.tripped(reason, self.settings.retry_after_s))

    def _reset_learning(self, time_s: float) -> None:
        """The waveform has faded out after a divergence: the model's plant again, learning later."""
        self.retry.faded_out(time_s, self.settings.retry_after_s)
        self._coefficients = np.zeros_like(self._coefficients)
        self._probe = np.zeros_like(self._probe)
        self._set_played()
        self._forget_learned_plant()

    def enter_zone(self, index: int) -> None:
        """The setpoint in use moved into zone ``index`` (from 0), whose model :meth:`reconfigure` has just taken.

        The plant learned belongs to the operating point it was learned at; the zone's model is the
        commissioned one for the new point, so the learned plant starts again from it, with the prior's
        spread: the probe starts again, the learned limit and the line PI alone left are forgotten. The
        waveform plays on (dropping it would be a bump) and is learned from there. Said as an event.
        """
        self._take_step_result()        # a step computed at the previous operating point is taken first
        self._pi_alone = None
        self._forget_learned_plant()
        self._move(FeedforwardEvent.PLANT_FORGOTTEN)
        self.report.zone_entered(index, self.settings.model_source)

    def _forget_learned_plant(self) -> None:
        """The model's plant again, with the prior's spread; the probe from its start, no learned limit."""
        self.worker.apply(SynchronousEstimator.reset_correction)
        self.probe_state = ProbeState.start(self.settings.harmonics)
        self.guard.clear()
        self.limits.forget_learned()
        self._estimate = replace(self._estimate, learned=LearnedPlant.from_model(self.plant).prepared())
        self._plant_known_for_limit = False
        self._probe_column = math.nan

    def _learned_limit_inputs(self, setpoint_K: float) -> LearnedLimitInputs | None:
        """What the learned limit is computed from, once the plant at the line is learned and T2 has settled at the
        setpoint; else None."""
        if not (self._plant_known_for_limit and self._setpoint_distance_K < SETTLED_K and self.mean_power_w is not None
                and self._estimate.ready and not self.retry.pending(self._time_s)):
            return None
        return LearnedLimitInputs(self.learned_plant, self._estimate.line.copy(), self.mean_power_w, self.output_max, setpoint_K,
                                  self.settings.period_s, self.setting_delay_s)


def _resized(values: np.ndarray, harmonics: int) -> np.ndarray:
    kept = np.zeros(harmonics, dtype=complex)
    count = min(harmonics, values.size)
    kept[:count] = values[:count]
    return kept
