"""A learning step of the feedforward, as its worker thread computes it.

Every ``update_interval_s`` the term (:mod:`cryod.control.feedforward.term`) takes, on the loop's
thread, what a step needs as values (:class:`LearningStep`) and hands it to its worker
(:mod:`cryod.control.feedforward.learning_worker`), which computes it after the readings handed over
before it: the line and the plant as the estimator knows them then
(:mod:`cryod.control.feedforward.synchronous_estimator`), T2's synchronous part with and without
the waveform, and, while the waveform plays, the probe's next turn
(:mod:`cryod.control.feedforward.plant_probe`) and the waveform stepped toward cancelling the line
and projected onto what the heater can play in the learned plant's metric
(:mod:`cryod.control.feedforward.learned_projection`). The term takes the :class:`StepResult` at the
next tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cryod.control.feedforward.learned_projection import learning_step
from cryod.control.feedforward.plant_learner import LearnedPlant
from cryod.control.feedforward.plant_probe import ProbeSettings, ProbeState, next_probe, probe_cost_K
from cryod.control.feedforward.synchronous_estimator import SynchronousEstimator

#: Phases of a cooler period at which the waveform is held within the heater's bounds (and, shrunk if
#: needed, on a grid eight times finer); 48 costs the 5 K optimum 0.2 % against 128, at a third of the time.
BOUND_POINTS = 48


@dataclass(frozen=True, eq=False)
class StepResult:
    """What a learning step found: the estimate, the plant learned, and the new waveform and probe (None: no step
    taken)."""

    ready: bool
    line: np.ndarray
    learned: LearnedPlant
    line_amplitude_K: float
    residual_K: float
    coefficients: np.ndarray | None
    probe: np.ndarray | None
    probe_state: ProbeState | None
    probe_cost_K: float

    @property
    def raw_correction(self) -> np.ndarray:
        return self.learned.correction

    @property
    def correction(self) -> np.ndarray:
        """The correction where learned, 1 elsewhere."""
        return np.where(self.learned.learned, self.learned.correction, 1.0)

    @classmethod
    def empty(cls, model_plant: np.ndarray) -> "StepResult":
        zeros = np.zeros(len(model_plant), dtype=complex)
        return cls(False, zeros, LearnedPlant.from_model(model_plant).prepared(), math.nan, math.nan, None, None, None,
                   0.0)


@dataclass(frozen=True, eq=False)
class LearningStep:
    """A learning step as the worker computes it, from values taken on the loop's thread.

    Attributes
    ----------
    plant : numpy.ndarray
        The controller model's plant at each harmonic as the loop samples it (K/W, complex).
    coefficients : numpy.ndarray
        The waveform's coefficients now (W, complex; the probe not included).
    effect : numpy.ndarray
        What the heater played last tick, through the model: its effect on T2 (K per harmonic).
    waveform_effect : numpy.ndarray
        The waveform's effect without the probe (K per harmonic): the residual the guard judges.
    learning : bool
        Whether the step moves the waveform and the probe (the waveform plays), or only estimates.
    gain : float
        Fraction of the way to the estimated best waveform.
    base_w, low_w, high_w : float
        The power the waveform rides on and the bounds it stays within (W).
    probe_state : ProbeState
        Where the probe is.
    probe : ProbeSettings
        How much the probe may move T2, and for what.
    interval_s : float
        Time between steps (s).
    frequency_rad_s : float
        The cooler's angular frequency now (rad/s).
    before : LearnedPlant or None
        The plant as the step before knew it (a harmonic is learned once two steps agree).
    approaching : bool
        T2 is still on its way to the setpoint (the probe may be larger).
    """

    plant: np.ndarray
    coefficients: np.ndarray
    effect: np.ndarray
    waveform_effect: np.ndarray
    learning: bool
    gain: float
    base_w: float
    low_w: float
    high_w: float
    probe_state: ProbeState
    probe: ProbeSettings
    interval_s: float
    frequency_rad_s: float
    before: LearnedPlant | None
    approaching: bool

    def __call__(self, estimator: SynchronousEstimator) -> StepResult:
        """The step, on the worker's thread, after the readings handed over before it was asked for."""
        ready = estimator.ready
        learned = estimator.learned_plant(self.plant, self.frequency_rad_s).confirmed_against(self.before).prepared()
        line_K = residual_K = math.nan
        if ready:
            line_K = _amplitude(estimator.synchronous(self.effect))
            residual_K = _amplitude(estimator.synchronous(self.waveform_effect))     # without the probe
        coefficients = probe = state = None
        cost = 0.0
        if ready and self.learning:
            room = min(self.base_w - self.low_w, self.high_w - self.base_w)
            state, probe = next_probe(self.probe_state, learned, room, self.interval_s, self.probe, self.approaching)
            reserved = float(np.sum(np.abs(probe)))
            coefficients = learning_step(self.coefficients, estimator.line, learned, self.gain, self.base_w,
                                         self.low_w + reserved, self.high_w - reserved, BOUND_POINTS)
            cost = probe_cost_K(probe, learned.plant)
            # no second difference may span the step: the readings before it decided it, and their noise
            # would look like the plant's answer to it
            estimator.forget_last()
        return StepResult(ready, estimator.line.copy(), learned, line_K, residual_K, coefficients, probe, state, cost)


def _amplitude(phasors: np.ndarray) -> float:
    return float(np.sqrt(np.sum(phasors.real ** 2 + phasors.imag ** 2)))


__all__ = ["BOUND_POINTS", "LearningStep", "StepResult"]
