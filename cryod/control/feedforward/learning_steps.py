"""The feedforward's learning steps on the loop's side: asked, taken, judged, and what they leave to report.

Every ``update_interval_s`` (:meth:`LearningSteps.due`) the term hands the learner's worker a step
(:meth:`LearningSteps.ask`: what :mod:`cryod.control.feedforward.learning_step` computes, as values)
and takes its result at the start of the next tick (:meth:`LearningSteps.take`), before that tick's
reading goes in, so the result is the same whatever the threads' timing: a step that moves the
waveform has it played from that tick's output on, and what the step found goes to the
feedforward's state machine (the probe playing, the plant at the line known or not, a
divergence). What this keeps between steps:

* the last step's estimate (the line, the plant as learned, T2's synchronous part) and the probe's
  state;
* the line PI alone leaves (the line estimated while no waveform played, with T5's amplitude then),
  against which the divergence guard (:mod:`cryod.control.feedforward.divergence_guard`) judges
  each step taken with the waveform at full (:meth:`LearningSteps.judge`), and the divergences with
  the wait they call for (:mod:`cryod.control.feedforward.divergence_retry`);
* what the learning says to the journal and the record
  (:mod:`cryod.control.feedforward.learning_report`), and ``ff_probe_K``;
* whether the plant at the line is known well enough (:data:`LIMIT_PLANT_SPREAD`) for the physical
  limit to be computed from what was learned.

Which state the feedforward is in, and so whether a step moves the waveform, is the term's
(:mod:`cryod.control.feedforward.state_machine`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from cryod.control.feedforward.divergence_guard import DivergenceGuard
from cryod.control.feedforward.divergence_retry import DivergenceRetry
from cryod.control.feedforward.learned_limit import LearnedLimitInputs
from cryod.control.feedforward.learning_report import LearningReport
from cryod.control.feedforward.learning_step import LearningStep, StepResult
from cryod.control.feedforward.learning_worker import LearningWorker
from cryod.control.feedforward.limit_follower import LimitFollower
from cryod.control.feedforward.plant_learner import LearnedPlant
from cryod.control.feedforward.plant_probe import ProbeState
from cryod.control.feedforward.played_waveform import PlayedWaveform
from cryod.control.feedforward.power_levels import PowerLevels
from cryod.control.feedforward.settings import FeedforwardSettings
from cryod.control.feedforward.state_machine import FeedforwardEvent
from cryod.control.feedforward.synchronous_estimator import SynchronousEstimator

#: Learning steps in a row that make a divergence (the guard's ``intervals``).
DIVERGENCE_STEPS = 5
#: The learned limit needs the plant at the line known to this (relative standard deviation).
LIMIT_PLANT_SPREAD = 0.1


class LearningSteps:
    """The learner's worker, the steps asked of it and what they found (module notes).

    Parameters
    ----------
    harmonics : int
    """

    def __init__(self, harmonics: int):
        self._worker: LearningWorker | None = None         # :attr:`worker`
        self._estimate: StepResult | None = None           # :attr:`estimate`
        self.probe_state = ProbeState.start(harmonics)
        self.guard = DivergenceGuard(DIVERGENCE_STEPS)
        self.report = LearningReport()
        self.retry = DivergenceRetry()
        #: (line with no waveform played (K), T5's amplitude then (K)), or None.
        self.pi_alone: tuple[float, float] | None = None
        #: T2's answer to the probe the last step set playing (K; NaN: none): the record's ``ff_probe_K``.
        self.probe_column = math.nan
        #: The plant at the line known to :data:`LIMIT_PLANT_SPREAD`: the limit may come from what was learned.
        self.plant_known_for_limit = False
        self._step_id = 0
        self._pending: int | None = None
        self._next_step_s: float | None = None
        self._synchronous: tuple | None = None

    @property
    def worker(self) -> LearningWorker:
        """The learner's thread (:meth:`use_estimator` starts it; the term does as it is made)."""
        if self._worker is None:
            raise RuntimeError("the feedforward's learner is not started: use_estimator first")
        return self._worker

    @property
    def estimate(self) -> StepResult:
        """What the last step found (before the first: the model's plant, nothing learned)."""
        if self._estimate is None:
            raise RuntimeError("the feedforward's learner is not started: use_estimator first")
        return self._estimate

    def needs_estimator(self, harmonics: int, memory_s: float) -> bool:
        """Whether the learner must start again (none yet, or another number of harmonics or memory)."""
        estimator = None if self._worker is None else self._worker.estimator
        return estimator is None or estimator.harmonics != harmonics or estimator.memory_s != memory_s

    def use_estimator(self, estimator: SynchronousEstimator, model_plant: np.ndarray) -> None:
        """Learn with ``estimator`` from now on, nothing known but ``model_plant`` (take the step pending first)."""
        if self._worker is not None:
            self._worker.close()
        self._worker = LearningWorker(estimator)
        self._estimate = StepResult.empty(model_plant)

    def due(self, time_s: float, interval_s: float) -> bool:
        """Whether a step is due at ``time_s`` (the first ``interval_s`` after the first asked)."""
        if self._next_step_s is None:
            self._next_step_s = time_s + interval_s
            return False
        if time_s < self._next_step_s:
            return False
        self._next_step_s += interval_s
        return True

    def ask(self, settings: FeedforwardSettings, plant: np.ndarray, waveform: PlayedWaveform, levels: PowerLevels,
            output_max: float, frequency_rad_s: float, moves: bool) -> None:
        """Hand the worker what a step needs, as values, to compute after the readings handed over so far.

        Parameters
        ----------
        settings : FeedforwardSettings
        plant : numpy.ndarray
            The controller model's plant at each harmonic as the loop samples it (K/W).
        waveform : PlayedWaveform
            What the heater plays.
        levels : PowerLevels
            The power the waveform rides on (none yet: no step).
        output_max : float
            The heater's largest power (W).
        frequency_rad_s : float
            The cooler's angular frequency now (rad/s).
        moves : bool
            The step moves the waveform and the probe (the waveform plays); else it only estimates.
        """
        if levels.other_terms_w is None:
            return
        self._step_id += 1
        self.worker.step(self._step_id, LearningStep(
            plant=plant.copy(), coefficients=waveform.coefficients.copy(), effect=waveform.effect(plant).copy(),
            waveform_effect=plant * waveform.coefficients * waveform.scale_played, learning=moves,
            gain=settings.learning_gain, base_w=levels.other_terms_w, low_w=settings.margin_W,
            high_w=output_max - settings.margin_W, probe_state=self.probe_state, probe=settings.probe,
            interval_s=settings.update_interval_s, frequency_rad_s=frequency_rad_s, before=self.estimate.learned,
            approaching=levels.approaching))
        self._pending = self._step_id

    def take(self, waveform: PlayedWaveform, at_full: bool, cooler_amplitude_K: float, time_s: float,
             retry_after_s: float, settled: bool = True) -> tuple[FeedforwardEvent, ...]:
        """The step asked for last (waiting for the worker if it is behind): its waveform and probe played from
        the next output on (a step that moves them), and judged; what it found, as the state machine's events.

        Parameters
        ----------
        waveform : PlayedWaveform
            What the heater plays.
        at_full : bool
            The waveform was at full when the step was asked (the guard judges only then).
        cooler_amplitude_K : float
            T5's line now (K; NaN: not tracked), to scale PI alone's line.
        time_s : float
            Now (s), for the report.
        retry_after_s : float
            The wait after a first divergence (s).
        settled : bool
            T2 at its setpoint: the report says a difference from the model only on settled data.

        Returns
        -------
        tuple of FeedforwardEvent
            ``PROBE_PLAYS``, ``PLANT_KNOWN`` or ``PLANT_UNKNOWN`` for a step that moved the waveform;
            ``DIVERGED`` when the guard tripped; nothing when no step was pending.
        """
        if self._pending is None:
            return ()
        result: StepResult = self.worker.result(self._pending)
        self._pending = None
        self._estimate = result
        plant = result.learned
        playing = result.coefficients is not None and result.probe_cost_K > 0.0
        self.probe_column = result.probe_cost_K if playing else math.nan
        self.plant_known_for_limit = bool(plant.learned[0] and plant.relative_spread[0] < LIMIT_PLANT_SPREAD)
        events: tuple[FeedforwardEvent, ...] = ()
        if result.coefficients is not None:      # a step that moves the waveform: asked while it played
            assert result.probe is not None and result.probe_state is not None     # a moving step sets all three
            waveform.set(result.coefficients, result.probe)
            self.probe_state = result.probe_state
            events = (FeedforwardEvent.PROBE_PLAYS if np.any(result.probe) else
                      FeedforwardEvent.PLANT_KNOWN if plant.learned[0] else FeedforwardEvent.PLANT_UNKNOWN),
        if result.ready and self._judge(result, time_s, waveform.coefficients, cooler_amplitude_K, at_full,
                                        retry_after_s, settled):
            events += FeedforwardEvent.DIVERGED,
        return events

    def _judge(self, result: StepResult, time_s: float, coefficients: np.ndarray, cooler_amplitude_K: float,
               at_full: bool, retry_after_s: float, settled: bool) -> bool:
        """After a ready step: what to report, PI alone's line, and the guard's verdict when the waveform was
        ``at_full``; whether it tripped (counted, reported, the wait set going)."""
        self.report.step(time_s, result.learned, self.probe_state.given_up(), settled)
        playing = np.any(coefficients)
        if not playing:
            self.pi_alone = (float(np.sqrt(np.sum(np.abs(result.line) ** 2))), cooler_amplitude_K)
        if not at_full or not playing:
            self.guard.clear()
            return False
        if self.pi_alone is not None and math.isfinite(cooler_amplitude_K) and self.pi_alone[1] > 0.0:
            pi_alone = self.pi_alone[0] * cooler_amplitude_K / self.pi_alone[1]
        else:
            pi_alone = float(np.sqrt(np.sum(np.abs(result.line) ** 2)))
        reason = self.guard.observe(result.residual_K, pi_alone)
        if reason is not None:
            self.report.diverged(reason, self.retry.tripped(reason, retry_after_s))
        return reason is not None

    def forget_plant(self, harmonics: int, model_plant: np.ndarray) -> None:
        """The model's plant again, with the prior's spread; the probe from its start."""
        self.worker.apply(SynchronousEstimator.reset_correction)
        self.probe_state = ProbeState.start(harmonics)
        self.guard.clear()
        self._estimate = replace(self.estimate, learned=LearnedPlant.from_model(model_plant).prepared())
        self.plant_known_for_limit = False
        self.probe_column = math.nan

    def keep_learned_plant(self, previous_plant: np.ndarray | None, plant: np.ndarray) -> None:
        """The controller's model changed from ``previous_plant`` to ``plant`` (K/W): the cryostat did not, so neither
        does the plant learned (in K/W; against the new model it is another correction)."""
        if previous_plant is not None and previous_plant.size == plant.size and \
                not np.allclose(previous_plant, plant, rtol=1e-12, atol=0.0):
            factor = previous_plant / plant
            self.worker.apply(lambda estimator: estimator.rescale_correction(factor))

    def learned_limit_inputs(self, levels: PowerLevels, time_s: float, setpoint_K: float, output_max: float,
                             period_s: float, setting_delay_s: float) -> LearnedLimitInputs | None:
        """What the limit is computed from once the plant at the line is learned and T2 has settled at the
        setpoint ``setpoint_K`` (its mean power the one the setpoint needs), not after a divergence's wait; else
        None. ``output_max`` (W), ``period_s`` and ``setting_delay_s`` (s): the heater and the loop's timing."""
        mean_power_w = levels.mean_power_w      # known once settled
        if not (self.plant_known_for_limit and levels.settled and mean_power_w is not None and self.estimate.ready
                and not self.retry.pending(time_s)):
            return None
        return LearnedLimitInputs(self.estimate.learned, self.estimate.line.copy(), mean_power_w, output_max,
                                  setpoint_K, period_s, setting_delay_s)

    def summary(self, limits: LimitFollower, setting_delay_s: float) -> dict:
        """What was learned, for ``--json``: the plant per harmonic, the limit reported and where it came from."""
        limit, plant = limits.limit, self.estimate.learned
        return {"feedforward_plant": plant.summary(), "feedforward_plant_differences": plant.differences(),
                "feedforward_reported_limit_K": None if limit is None else limit.ptc_periodic_limit_K,
                "feedforward_reported_authority": None if limit is None else limit.authority,
                "feedforward_limit_from": limits.source, "feedforward_probe_K": self.estimate.probe_cost_K,
                "feedforward_divergences": self.retry.count, "feedforward_setting_delay_s": setting_delay_s}

    def zone_entered(self, index: int, settings: FeedforwardSettings, model_plant: np.ndarray) -> None:
        """The setpoint in use moved into zone ``index`` (from 0), another operating point: the learned plant and PI
        alone's line are dropped, learning starts again from the zone's model (``model_plant``); said."""
        self.pi_alone = None
        self.forget_plant(settings.harmonics, model_plant)
        self.report.zone_entered(index, settings.model_source)

    def synchronous(self, effect: np.ndarray) -> list[complex]:
        """T2's synchronous part ``L_n + k_n z_n`` as the last step estimated it, for the waveform's ``effect``
        now (K per harmonic, plain complex; cached)."""
        cache, estimate = self._synchronous, self.estimate
        if cache is None or cache[0] is not estimate or cache[1] is not effect:
            phasors = estimate.line + estimate.learned.correction * effect
            cache = self._synchronous = (estimate, effect, [complex(value) for value in phasors])
        return cache[2]

    def close(self) -> None:
        """End the learner's thread."""
        if self._worker is not None:
            self._worker.close()


__all__ = ["DIVERGENCE_STEPS", "LIMIT_PLANT_SPREAD", "LearningSteps"]
