"""The feedforward: a heater waveform locked to the cooler that cancels its line on the flange.

PI cannot remove the pulse-tube cooler's oscillation from T2 (docs/control.md):
at 10.8 rad/s the heater reaches T2 only through G2*G1, about 7 mK/W lagging
90 degrees, and a feedback loop that tried would need far more gain than the
80 ms loop allows. The cooler's own oscillation, seen in T5 at hundreds of
times its noise, gives the phase; the heater can then play a waveform locked
to that phase whose effect on T2 cancels the line.

How it works, every tick:

1. **Phase** (:mod:`cryod.control.cooler_phase`): T5, at the instant its
   reading stands for, updates a phase-locked loop; lock, phase and
   frequency come out.
2. **Estimate** (:class:`SynchronousEstimator`): T2, at its own instant, updates
   a Kalman filter of T2's part synchronous with the cooler (harmonics 1 to N
   of the tracked phase), split into the cooler's line and the waveform's
   effect through the model's plant response times a correction learned from
   how T2 answers the waveform's changes. The PI term is given T2 without the
   estimated synchronous part, so it does not chase the line (and the
   feedforward's plant is the open-loop one).
3. **Waveform**: the heater part is ``Re(sum_n u_n exp(j n phase))``, a
   band-limited waveform (no mean, so the mean heater power stays PI's; no
   harmonics above N, so none alias below 2 Hz through the 80 ms hold),
   evaluated at the phase of the middle of the coming hold. Its effect on T2's
   samples is the plant *as the loop samples it*
   (:func:`plant_at_harmonics`): above half the sampling rate the hold's
   folded images make it differ much from ``G(j n omega)``.
4. **Learning** (iterative learning in the cooler's phase): every
   ``update_interval_s`` the coefficients step toward cancelling the estimated
   line, ``u <- u + gain (-L / G_n - u)``, and are projected onto what the
   heater can do, ``margin <= PI's power + waveform <= R I_max^2 - margin`` at
   every phase, in the metric of the plant response: the fixed point is the
   constrained optimum, the physical limit of :mod:`cryod.control.feedforward_limit`.
   The first waveform comes from the model (its line scaled to T5's amplitude).
5. **Fade**: without lock (cooler stopped, T5 fault) or when switched off,
   the waveform fades out over ``fade_time_s``; PI carries on. Switching on,
   or closing the loop, fades it in. Readings after a gap (a fault, start-up)
   or a tick where the total was held at a limit are left out of the estimate.

The term rides on the feedback (``rides_on_feedback``): the regulator adds it
after PI's sum has been held within the heater's range, so a clipped waveform
never stops PI integrating.

Configuration, section ``control.feedforward`` (optional; reloadable, bumpless)::

    feedforward:
      enabled: true              # cryod ctl feedforward on|off switches it without a reload
      harmonics: 6
      update_interval_s: 2.0     # the waveform steps this often
      memory_s: 60.0             # the line estimate may drift over this
      learning_gain: 0.5         # fraction of the way to the estimated best waveform per step
      fade_time_s: 5.0
      margin_W: 0.001            # kept from 0 W and from R I_max^2
      minimum_cooler_amplitude_K: 0.01
      model: null                # the controller's model (null: the shipped model)
"""

from __future__ import annotations

import cmath
import math
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cryod.control.bounded_waveform import best_bounded_waveform, waveform_values
from cryod.control.cooler_phase import CoolerPhaseTracker
from cryod.control.feedforward_learning import LearningWorker
from cryod.control.terms import TickInputs
from cryod.control.unplayed_power import UnplayedPower
from cryod.control.feedforward_limit import FeedforwardLimitError, limit_changes, limit_for_heater_power
from cryod.control.harmonic_plant import line_at_harmonics, plant_at_harmonics
from cryod.model import DEFAULT_MODEL_PATH, CryostatModel, load_model
from cryod.records.columns import Column
from cryod.service.realtime import at_normal_priority
from cryod.yaml_source import FileFormatError, Section

#: Loop period the plant response assumes when the settings do not say (s).
DEFAULT_PERIOD_S = 0.08
#: A plant correction is used once its standard deviation is below this (else the model's response).
TRUSTED_CORRECTION_SPREAD = 0.3
#: After a gap in the loop (a fault, start-up), T2's readings are left out this long (s).
SETTLE_S = 1.0
#: Smoothing of the feedback terms' power, the level the waveform rides on (s).
BASE_TIME_S = 2.0
#: Second differences the estimator takes into one update of its filter.
BATCH = 4
#: Phases of a cooler period at which the waveform is held within the heater's bounds (and, shrunk if
#: needed, on a grid eight times finer); 48 costs the 5 K optimum 0.2 % against 128, at a third of the time.
BOUND_POINTS = 48
#: The physical limit is computed once the setpoint has been steady this long (s).
LIMIT_AFTER_S = 5.0
#: ... on a thread of its own (with what would change it: some 60 ms of computing), and taken this long
#: after it was asked for (s): in service it is long done; on virtual time the loop waits, so runs stay
#: deterministic.
LIMIT_TAKEN_AFTER_S = 2.0
#: The plant response is recomputed when the delay from T2's sample to the heater setting moves by more (s).
SETTING_DELAY_TOLERANCE_S = 0.002


@dataclass(frozen=True)
class FeedforwardSettings:
    """The ``control.feedforward`` section.

    Attributes
    ----------
    enabled : bool
        On at start (``cryod ctl feedforward on|off`` switches it while running).
    harmonics : int
        Harmonics of the cooler frequency in the waveform and the residual.
    update_interval_s : float
        The waveform steps this often (s).
    memory_s : float
        Memory of the estimate of T2's synchronous part (s).
    learning_gain : float
        Fraction of the way to the estimated best waveform taken per step (0 to 1).
    fade_time_s : float
        Fade in and out (s).
    margin_W : float
        Distance kept from 0 W and from R I_max^2 (W).
    minimum_cooler_amplitude_K : float
        T5 oscillation below this counts as no cooler signal (K).
    model : CryostatModel
        The controller's model (plant response at each harmonic, first waveform).
    model_source : str
        Where the model came from.
    period_s : float
        Loop period (s): the hold of each heater setting.
    """

    enabled: bool = True
    harmonics: int = 6
    update_interval_s: float = 2.0
    memory_s: float = 60.0
    learning_gain: float = 0.5
    fade_time_s: float = 5.0
    margin_W: float = 0.001
    minimum_cooler_amplitude_K: float = 0.01
    model: CryostatModel | None = None
    model_source: str = "shipped model"
    period_s: float = DEFAULT_PERIOD_S

    @property
    def controller_model(self) -> CryostatModel:
        return self.model if self.model is not None else load_model(DEFAULT_MODEL_PATH)


class SynchronousEstimator:
    """T2's part synchronous with the cooler, split into the cooler's line and the waveform's effect.

    Model of T2 at each reading (phase ``theta`` of the cooler)::

        T2 = slow part + Re(sum_n (L_n + k_n z_n) exp(j n theta)) + noise

    with ``L_n`` the cooler's line (it does not change when the waveform does),
    ``z_n`` the waveform's effect through the controller's model (its
    coefficient times the model's plant response, known) and ``k_n`` the
    correction of the model's plant response (1 when the model is right).

    Second differences of successive readings remove the slow part (what is
    left, its curvature, is a thousandth of the line and not synchronous). A
    Kalman filter estimates ``L`` and ``k``, each a slow random walk: the line
    by about ``line_drift_K`` per ``memory_s`` (a cooler frequency wandering by
    a percent changes T2's line by a percent), the plant's correction by a
    tenth per hour. ``k`` is learned only from readings where the
    waveform changes (when it comes in, when it learns) and is kept between
    them; it starts at 1 with a spread of ``correction_spread``.

    Where the waveform hardly changes, the readings hardly tell ``k_n``, and a
    change the estimate's own noise decided even biases it (the noise that moved
    the waveform is still in the estimate of the line): ``k_n`` is used only
    once its spread is below ``TRUSTED_CORRECTION_SPREAD``, else the model's
    response is. Where that happens the waveform is small, and so is the harm.

    Parameters
    ----------
    harmonics : int
    noise_K : float
        T2's reading noise (K rms), for the filter's measurement noise.
    memory_s : float
        Time over which the line may change by about ``line_drift_K`` (s).
    period_s : float
        Typical interval between readings (s).
    correction_spread : float
        Prior spread of ``k`` around 1.
    line_drift_K : float
        How much the line may change over ``memory_s`` (K).
    """

    #: The correction of the plant may drift by about this fraction per hour.
    CORRECTION_DRIFT_PER_HOUR = 0.1

    def __init__(self, harmonics: int, noise_K: float = 20e-6, memory_s: float = 60.0,
                 period_s: float = DEFAULT_PERIOD_S, correction_spread: float = 0.7, line_drift_K: float = 20e-6):
        self.harmonics = harmonics
        self.memory_s = memory_s
        self.orders = np.arange(1, harmonics + 1)
        self.size = 4 * harmonics
        n = 2 * harmonics
        line_scale = 3e-3           # K: a line of mK at most
        steps = memory_s / period_s
        self._process = np.concatenate([np.full(n, line_drift_K ** 2 / steps),
                                        np.full(n, self.CORRECTION_DRIFT_PER_HOUR ** 2 * period_s / 3600.0)])
        self.covariance = np.diag(np.concatenate([np.full(n, line_scale ** 2), np.full(n, correction_spread ** 2)]))
        self.state = np.concatenate([np.zeros(n), np.ones(harmonics), np.zeros(harmonics)])
        self.measurement_variance = 6.0 * noise_K ** 2     # second difference of white noise
        self._history: list[tuple[np.ndarray, float]] = []     # the last two readings' regressors and T2
        self._pending: list[tuple[np.ndarray, float]] = []     # a second difference waiting for its pair
        self.samples = 0
        self._covariance_diagonal = self.covariance.reshape(-1)[::self.size + 1]

    @property
    def line(self) -> np.ndarray:
        n = self.harmonics
        return self.state[:n] + 1j * self.state[n:2 * n]

    @property
    def raw_correction(self) -> np.ndarray:
        """The filter's estimate of ``k_n`` as it stands, trusted or not (K/K, complex)."""
        n = self.harmonics
        return self.state[2 * n:3 * n] + 1j * self.state[3 * n:]

    @property
    def correction(self) -> np.ndarray:
        """The plant correction at each harmonic where the readings tell it (its spread below a quarter
        of its size), else 1: the model's."""
        n = self.harmonics
        raw = self.state[2 * n:3 * n] + 1j * self.state[3 * n:]
        variance = np.diag(self.covariance)
        spread = np.sqrt(np.maximum(variance[2 * n:3 * n] + variance[3 * n:], 0.0))
        raw = np.where(spread < TRUSTED_CORRECTION_SPREAD, raw, 1.0)
        return np.clip(np.abs(raw), 0.2, 5.0) * np.exp(1j * np.clip(np.angle(raw), -1.4, 1.4))

    def regressors(self, phase: float, effect: np.ndarray) -> np.ndarray:
        """[cos, -sin of each harmonic, Re and -Im of each effect turned by the phase] at one reading."""
        rotors = np.exp(1j * self.orders * phase)
        turned = effect * rotors
        row = np.empty(self.size)
        n = self.harmonics
        row[:n], row[n:2 * n], row[2 * n:3 * n], row[3 * n:] = rotors.real, -rotors.imag, turned.real, -turned.imag
        return row

    def synchronous(self, effect: np.ndarray) -> np.ndarray:
        """T2's synchronous part per harmonic as estimated now, ``L_n + k_n z_n`` (K, complex)."""
        return self.line + self.raw_correction * effect

    def add(self, phase: float, flange_K: float, effect: np.ndarray) -> None:
        """One T2 reading at its phase, with the waveform's modelled effect ``effect`` (K per harmonic)."""
        self._history.append((self.regressors(phase, effect), flange_K))
        if len(self._history) < 3:
            return
        (row0, y0), (row1, y1), (row2, y2) = self._history
        del self._history[0]
        self._pending.append((row2 - 2.0 * row1 + row0, y2 - 2.0 * y1 + y0))
        self.samples += 1
        if len(self._pending) == BATCH:
            self._update_batch()

    def _update_batch(self) -> None:
        """The filter's update with BATCH second differences at once (a fraction of the cost per reading
        of one at a time, the same information): covariance grown by as many steps of drift, then the gain."""
        observed = np.array([x for x, _ in self._pending])      # BATCH x size
        differences = np.array([d for _, d in self._pending])
        self._pending.clear()
        covariance = self.covariance
        self._covariance_diagonal += len(differences) * self._process      # a strided view of the diagonal
        px = covariance @ observed.T                            # size x BATCH
        innovation_covariance = observed @ px
        innovation_covariance.reshape(-1)[::len(differences) + 1] += self.measurement_variance
        gain = np.linalg.solve(innovation_covariance, px.T).T   # size x BATCH (symmetric system)
        self.state += gain @ (differences - observed @ self.state)
        covariance -= gain @ px.T
        covariance += covariance.T                              # kept symmetric against rounding
        covariance *= 0.5

    @property
    def ready(self) -> bool:
        """Enough readings for a first estimate."""
        return self.samples >= 8 * self.harmonics

    def forget_last(self) -> None:
        """Do not difference the next reading against the last ones (a gap: the lock was lost)."""
        self._history.clear()
        if self._pending:                    # what is waiting for a full batch: its update now
            self._update_batch()


class FeedforwardTerm:
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
                                  "waveform can leave (feedforward-limit; empty until computed)", "{:.4e}"),
        Column("ff_authority", "", "largest fundamental the heater can give over the one the line needs "
                                   "(below 1: authority-limited)", "{:.4f}"),
    )

    def __init__(self, settings: FeedforwardSettings, output_max: float):
        self.output_max = output_max
        self.switched_on = settings.enabled
        self.scale = 0.0
        self.coefficients = np.zeros(settings.harmonics, dtype=complex)
        self.tracker: CoolerPhaseTracker | None = None
        self.worker: LearningWorker | None = None         # the estimator and the learning steps
        self._estimate = StepResult.empty(settings.harmonics)  # what the last learning step returned
        self._step_id = 0
        self._pending_step: int | None = None
        self.setting_delay_s = 0.0
        self.other_terms_w: float | None = None      # the feedback terms' power, smoothed
        self.output_w = 0.0
        self.phase = None
        self._flange_phase_rad = math.nan
        self._applied_scale = 0.0           # the scale of the waveform the heater played last tick
        self._held_since_s = -math.inf      # when the loop last had a gap (the heater held off)
        self._played = False                # update() ran last tick: the heater played the waveform
        self._output_time_s = 0.0           # when this tick's power takes effect
        self.unplayed: UnplayedPower | None = None      # the power held back at the heater's bounds
        self._next_update_s: float | None = None
        self._in_gap = False                # the worker was told of a gap since the last reading
        self._synchronous_cache = None
        #: The physical limit at the setpoint in use (:mod:`cryod.control.feedforward_limit`); None until the
        #: setpoint has been steady for LIMIT_AFTER_S (a few ms to compute, once per setpoint).
        self.physical_limit = None
        #: The limit if the setpoint moved by 0.5 K either way, or R I_max^2 doubled (LimitChange, with it).
        self.limit_changes: tuple = ()
        self._limit_wanted: tuple[float, float] | None = None       # (setpoint, since when)
        self._limit_executor: ThreadPoolExecutor | None = None
        self._limit_asked: tuple[Future, float, float] | None = None     # (result, setpoint, when to take it)
        self._configure(settings)

    # -- configuration ---------------------------------------------------------------
    @staticmethod
    def settings_from(section: Section | None) -> FeedforwardSettings:
        """The ``control.feedforward`` section (defaults when absent)."""
        if section is None:
            return FeedforwardSettings(model=load_model(DEFAULT_MODEL_PATH))
        defaults = FeedforwardSettings()
        model_path = section.text("model", None)
        try:
            model = load_model(_resolve(model_path, section.source)) if model_path else load_model(DEFAULT_MODEL_PATH)
        except FileFormatError as error:
            raise section.error("model", f"controller model not usable: {error}") from None
        settings = FeedforwardSettings(
            enabled=section.flag("enabled", defaults.enabled),
            harmonics=section.number("harmonics", defaults.harmonics, minimum=1, maximum=12, integer=True),
            update_interval_s=section.number("update_interval_s", defaults.update_interval_s, minimum=0.5,
                                             maximum=60.0),
            memory_s=section.number("memory_s", defaults.memory_s, minimum=2.0, maximum=3600.0),
            learning_gain=section.number("learning_gain", defaults.learning_gain, minimum=0.0,
                                         exclusive_minimum=True, maximum=1.0),
            fade_time_s=section.number("fade_time_s", defaults.fade_time_s, minimum=0.0, maximum=600.0),
            margin_W=section.number("margin_W", defaults.margin_W, minimum=0.0, maximum=1.0),
            minimum_cooler_amplitude_K=section.number("minimum_cooler_amplitude_K",
                                                      defaults.minimum_cooler_amplitude_K, minimum=0.0,
                                                      exclusive_minimum=True),
            model=model, model_source=model_path or "shipped model")
        section.finish()
        return settings

    def _configure(self, settings: FeedforwardSettings) -> None:
        previous = getattr(self, "settings", None)
        if previous is not None and previous.controller_model != settings.controller_model:
            self.physical_limit, self.limit_changes = None, ()      # computed again for the new model
        self.settings = settings
        model = settings.controller_model
        harmonics = settings.harmonics
        if self.tracker is None or self.tracker.nominal_rad_s != model.ptc.angular_frequency_rad_s \
                or self.tracker.minimum_amplitude_K != settings.minimum_cooler_amplitude_K:
            self.tracker = CoolerPhaseTracker(model.ptc.angular_frequency_rad_s,
                                              minimum_amplitude_K=settings.minimum_cooler_amplitude_K)
        self._orders = np.arange(1, harmonics + 1)
        self.unplayed = UnplayedPower(model)
        self.plant = plant_at_harmonics(model, self._orders, settings.period_s, self.setting_delay_s)
        self._effect_cache = None
        self.model_line = line_at_harmonics(model, harmonics)
        self._model_stage_amplitude_K = abs(model.ptc.ptc_stage_amplitude_K) or 1.0
        if self.coefficients.size != harmonics:                    # keep what was learned, as far as it goes
            kept = np.zeros(harmonics, dtype=complex)
            count = min(harmonics, self.coefficients.size)
            kept[:count] = self.coefficients[:count]
            self.coefficients = kept
        worker = self.worker
        if worker is None or worker.estimator.harmonics != harmonics or worker.estimator.memory_s != settings.memory_s:
            if worker is not None:
                self._take_step_result()
                worker.close()
            self.worker = LearningWorker(SynchronousEstimator(harmonics, model.sensor_noise.flange_thermometer_rms_K,
                                                              settings.memory_s, settings.period_s))
            self._estimate = StepResult.empty(harmonics)
        self._started = bool(np.any(self.coefficients))

    def reconfigure(self, settings: FeedforwardSettings, output_max: float) -> None:
        """A reload: new settings, keeping the lock and the learned waveform (bumpless)."""
        self.output_max = output_max
        if settings.enabled != self.settings.enabled:
            self.switched_on = settings.enabled
        self._configure(settings)

    def close(self) -> None:
        """End the learning thread (the regulator closes its terms when the loop stops)."""
        if self.worker is not None:
            self.worker.close()
        if self._limit_executor is not None:
            self._limit_executor.shutdown(wait=False, cancel_futures=True)
            self._limit_executor = None
            self._limit_asked = None

    def switch(self, on: bool) -> None:
        """``cryod ctl feedforward on|off``: fade in or out."""
        self.switched_on = bool(on)

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
        if phase.time_s - self._held_since_s < SETTLE_S:
            # after a gap the heater did not play the waveform the estimator assumes: wait until T2 has settled
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
            phasors = self._estimate.line + self._estimate.raw_correction * effect
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

    def update(self, tick: TickInputs) -> float:
        self._played = True
        self._output_time_s = tick.output_time_s
        locked = self.phase is not None and self.phase.locked
        wanted = 1.0 if (self.switched_on and locked) else 0.0
        fade = self.settings.fade_time_s
        step = tick.dt_s / fade if fade > 0.0 else 1.0
        self.scale = min(self.scale + step, wanted) if wanted > self.scale else max(self.scale - step, wanted)
        if locked and (self.switched_on or self.scale > 0.0):
            if self._next_update_s is None:
                self._next_update_s = tick.time_s + self.settings.update_interval_s
            elif tick.time_s >= self._next_update_s:
                self._next_update_s += self.settings.update_interval_s
                self._ask_for_step()
        self._follow_limit(tick)
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
        self.output_w = self.scale * value
        return self.output_w

    @property
    def coefficients(self) -> np.ndarray:
        """The waveform's complex amplitudes ``u_n`` (W), n = 1..harmonics."""
        return self._coefficients

    @coefficients.setter
    def coefficients(self, values) -> None:
        self._coefficients = np.asarray(values, dtype=complex)
        self._coefficient_list = [complex(value) for value in self._coefficients]
        self._effect_cache = None

    def _effect(self) -> np.ndarray:
        """The waveform's effect on T2 through the model, as the heater played it last tick (K per harmonic)."""
        scale = self._applied_scale
        if self._effect_cache is None or self._effect_cache[0] != scale:
            self._effect_cache = (scale, self.plant * self._coefficients * scale)
        return self._effect_cache[1]

    def _follow_limit(self, tick: TickInputs) -> None:
        """Compute the physical limit for a setpoint once it has been steady for LIMIT_AFTER_S (on a thread
        of its own, taken LIMIT_TAKEN_AFTER_S later)."""
        if self._limit_asked is not None:
            result, setpoint, take_at_s = self._limit_asked
            if tick.time_s < take_at_s:
                return
            self._limit_asked = None
            self.physical_limit, self.limit_changes = result.result()
            if self.physical_limit is None:
                self._limit_wanted = (setpoint, math.inf)       # out of reach: not again for this setpoint
            return
        setpoint = round(tick.setpoint_K, 4)
        if self._limit_wanted is None or self._limit_wanted[0] != setpoint:
            self._limit_wanted = (setpoint, tick.time_s)
            return
        known = self.physical_limit
        if known is not None and known.setpoint_K == setpoint \
                and abs(known.heater_delay_s - self.setting_delay_s) < SETTING_DELAY_TOLERANCE_S \
                and known.max_heater_power_W == self.output_max:
            return
        if tick.time_s - self._limit_wanted[1] < LIMIT_AFTER_S:
            return
        if self._limit_executor is None:
            self._limit_executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cryod-feedforward-limit",
                                                      initializer=at_normal_priority)
        result = self._limit_executor.submit(_limit_report, self.settings.controller_model, setpoint, self.output_max,
                                             self.settings.period_s, self.setting_delay_s)
        self._limit_asked = (result, setpoint, tick.time_s + LIMIT_TAKEN_AFTER_S)

    def limit(self, requested: float, applied: float) -> None:
        others = requested - self.output_w
        if self.other_terms_w is None:
            self.other_terms_w = others
        else:       # the other terms' power, smoothed over about 2 s: the level the waveform rides on
            self.other_terms_w += (others - self.other_terms_w) * min(self.settings.period_s / BASE_TIME_S, 1.0)
        self.unplayed.set(self._output_time_s, applied - requested)

    def column_values(self) -> tuple[float, ...]:
        phase = self.phase
        known = self.physical_limit
        limit, authority = (known.ptc_periodic_limit_K, known.authority) if known is not None else (math.nan,) * 2
        if phase is None:
            return (self.output_w, math.nan, math.nan, 0.0, math.nan, self.scale, limit, authority)
        return (self.output_w, self._flange_phase_rad, phase.frequency_rad_s, 1.0 if phase.locked else 0.0,
                self._estimate.line_amplitude_K, self.scale, limit, authority)

    def describe(self) -> str:
        """The feedforward's state in a few lines (``cryod ctl feedforward status``)."""
        phase = self.phase
        lines = [f"feedforward {'on' if self.switched_on else 'off'}, waveform at {100 * self.scale:.0f} % "
                 f"(fade {self.settings.fade_time_s:g} s)"]
        if phase is None:
            lines.append("cooler phase: not tracked (off, or no reading yet)")
        else:
            lines.append(f"cooler phase {'locked' if phase.locked else 'NOT locked'}: {phase.frequency_rad_s:.4f} rad/s "
                         f"({phase.frequency_rad_s / (2 * math.pi):.4f} Hz), T5 line {1e3 * phase.amplitude_K:.1f} mK")
        line = self.line_amplitude_K()
        if math.isfinite(line):
            harmonics = ", ".join(f"{1e6 * abs(value):.1f}" for value in self._synchronous_list())
            lines.append(f"T2's part synchronous with the cooler: {1e6 * line:.1f} µK (harmonics 1-"
                         f"{self.settings.harmonics}: {harmonics} µK); without the waveform it would be "
                         f"{1e6 * float(np.sqrt(np.sum(np.abs(self._estimate.line) ** 2))):.1f} µK")
        amplitude = np.abs(self.coefficients)
        values = waveform_values(self.coefficients, self.other_terms_w or 0.0, BOUND_POINTS)
        lines.append(f"waveform: {', '.join(f'{1e3 * a:.1f}' for a in amplitude)} mW per harmonic, "
                     f"{1e3 * values.min():.1f} to {1e3 * values.max():.1f} mW with the "
                     f"{1e3 * (self.other_terms_w or 0.0):.1f} mW from PI, within {1e3 * self.settings.margin_W:g} mW "
                     f"of 0 and {1e3 * self.output_max:.0f} mW")
        correction = self._estimate.correction[0]
        lines.append(f"plant at the fundamental: {abs(correction):.2f} x the model's, "
                     f"{math.degrees(cmath.phase(correction)):+.0f} deg (model: {self.settings.model_source})")
        limit = self.physical_limit
        if limit is None:
            lines.append("physical limit: not computed yet (the daemon computes it for the setpoint in use)")
        else:
            lines.append(f"physical limit at {limit.setpoint_K:g} K: {1e6 * limit.ptc_periodic_limit_K:.1f} µK of the "
                         f"{1e6 * limit.open_line_K:.1f} µK line; {limit.limited_by}-limited (authority "
                         f"{limit.authority:.2f}: the heater can put {1e3 * limit.largest_line_power_W:.0f} mW at the "
                         f"line of the {1e3 * limit.line_power_needed_W:.0f} mW needed); predicted best "
                         f"{1e6 * limit.predicted_best_residual_K:.1f} µK")
            if self.limit_changes:
                lines.append("what would change it: " + "; ".join(change.describe() for change in self.limit_changes)
                             + " (R I_max^2 x 2: R x 2 or I_max x 1.41; more: cryod feedforward-limit)")
        return "\n".join(lines)

    def line_amplitude_K(self) -> float:
        """T2's synchronous part as estimated at the last learning step (K; NaN before there is one)."""
        return self._estimate.line_amplitude_K

    # -- learning (the worker computes, the loop takes the result at the next tick) ---------
    def _ask_for_step(self) -> None:
        """Hand the worker what a learning step needs, as values, to compute after the readings so far."""
        if self.other_terms_w is None:
            return
        self._step_id += 1
        first = None
        if not self._started:
            # the first waveform from the model: its line on T2, scaled to the cooler's amplitude in T5
            first = -self.model_line * (self.tracker.amplitude_K / self._model_stage_amplitude_K)
        self.worker.step(self._step_id, _LearningStep(
            plant=self.plant.copy(), coefficients=self._coefficients.copy(), effect=self._effect().copy(),
            first_line=first, gain=self.settings.learning_gain, base_w=self.other_terms_w,
            low_w=self.settings.margin_W, high_w=self.output_max - self.settings.margin_W))
        self._pending_step = self._step_id

    def _take_step_result(self) -> None:
        """Apply the step asked for last tick (waiting for the worker if it is behind)."""
        if self._pending_step is None:
            return
        result = self.worker.result(self._pending_step)
        self._pending_step = None
        self._estimate = result
        if result.coefficients is not None:
            self._started = True
            self.coefficients = result.coefficients


def _limit_report(model: CryostatModel, setpoint_K: float, max_power_w: float, period_s: float,
                  delay_s: float) -> tuple:
    """(the physical limit, what would change it) at a setpoint, or (None, ()) when it is out of reach."""
    try:
        limit = limit_for_heater_power(model, setpoint_K, max_power_w, period_s, heater_delay_s=delay_s,
                                       certify=False)
    except FeedforwardLimitError:
        return None, ()
    return limit, limit_changes(model, setpoint_K, max_power_w, period_s, heater_delay_s=delay_s)


@dataclass(frozen=True, eq=False)
class StepResult:
    """What a learning step found: the estimate, and the new coefficients (None: no step taken)."""

    ready: bool
    line: np.ndarray
    raw_correction: np.ndarray
    correction: np.ndarray
    line_amplitude_K: float
    coefficients: np.ndarray | None

    @classmethod
    def empty(cls, harmonics: int) -> "StepResult":
        zeros, ones = np.zeros(harmonics, dtype=complex), np.ones(harmonics, dtype=complex)
        return cls(False, zeros, ones, ones, math.nan, None)


@dataclass(frozen=True, eq=False)
class _LearningStep:
    """A learning step as the worker computes it, from values taken on the loop's thread."""

    plant: np.ndarray
    coefficients: np.ndarray
    effect: np.ndarray
    first_line: np.ndarray | None
    gain: float
    base_w: float
    low_w: float
    high_w: float

    def __call__(self, estimator: SynchronousEstimator) -> StepResult:
        ready = estimator.ready
        synchronous = estimator.synchronous(self.effect)
        line_K = float(np.sqrt(np.sum(synchronous.real ** 2 + synchronous.imag ** 2))) if ready else math.nan
        correction = estimator.correction
        raw = estimator.raw_correction
        coefficients = None
        if ready:
            plant = self.plant * correction
            if self.first_line is not None:
                stepped = self.first_line / plant
            else:
                stepped = self.coefficients + self.gain * (-estimator.line / plant - self.coefficients)
            # the feasible waveform closest to the step in the plant's metric: min sum |H_n (u_n - stepped_n)|^2
            coefficients = best_bounded_waveform(-plant * stepped, plant, self.base_w, self.low_w, self.high_w,
                                                 phase_points=BOUND_POINTS)
            # no second difference may span the step: the readings before it decided it, and their noise
            # would look like the plant's answer to it
            estimator.forget_last()
        return StepResult(ready, estimator.line.copy(), raw.copy(), correction, line_K, coefficients)


def _resolve(path: str, config_source: str) -> Path:
    candidate = Path(path).expanduser()
    if not candidate.is_absolute() and config_source and not config_source.startswith("<"):
        candidate = Path(config_source).resolve().parent / candidate
    return candidate
