"""Which of T2's readings the feedforward's learner takes, and as what.

While the cooler's phase is locked, every T2 reading goes to the learner
(:mod:`cryod.control.feedforward.synchronous_estimator`, on its worker thread) with its phase and
the effect the waveform the heater played had on it, except:

* for :data:`SETTLE_S` after a gap in the loop (a fault, start-up: the heater was held off, not
  playing the waveform the learner assumes);
* for :data:`CHANGE_SETTLE_S` after a change of what the heater plays that moves T2 by more than
  :data:`CHANGE_SETTLE_ABOVE_K` (a thermometer that lags or a heater that acts late answers the old
  waveform and the new one mixed for a while; taken as the new one's answer they would bias the
  plant learned by the change);

and the learner is told of each such gap once (no second difference spans it). Where the
regulator held the heater's total at a bound, the reading is corrected to T2 as it would have been
had the heater played what was asked (:mod:`cryod.control.feedforward.unplayed_power`): every reading
counts, clipped or not.
"""

from __future__ import annotations

import math

import numpy as np

from cryod.control.feedforward.learning_worker import LearningWorker
from cryod.control.feedforward.unplayed_power import UnplayedPower
from cryod.control.terms import TickInputs
from cryod.cooler.phase import CoolerPhase

#: After a gap in the loop (a fault, start-up), T2's readings are left out this long (s).
SETTLE_S = 1.0
#: After a change of what the heater plays (a learning step, the probe turning), T2's readings are left out this
#: long (s) ...
CHANGE_SETTLE_S = 0.5
#: ... when the change moves T2 by more than this (K, through the model's plant): a change of a few microkelvin (a
#: converged waveform following the line's noise) mixes nothing that matters against the readings' noise.
CHANGE_SETTLE_ABOVE_K = 20e-6


class ReadingFeed:
    """T2's readings into the learner, with the gaps where the heater did not play what it assumes (module notes)."""

    def __init__(self, unplayed: UnplayedPower):
        #: The power the regulator held back at the heater's bounds, as T2 answers it (the term's model's).
        self.unplayed = unplayed
        self._held_since_s = -math.inf      # when the loop last had a gap (the heater held off)
        self._changed_at_s = -math.inf      # when the heater began to play a new waveform or probe
        self._in_gap = False                # the learner was told of a gap since the last reading

    def gap(self, worker: LearningWorker) -> None:
        """No reading now: the next is not to be differenced against the last ones (said once per gap)."""
        if not self._in_gap:
            self._in_gap = True
            worker.gap()

    def heater_changed(self, output_time_s: float, change_K: float) -> None:
        """The heater plays a new waveform or probe from ``output_time_s``, moving T2 by ``change_K`` (K)."""
        if change_K > CHANGE_SETTLE_ABOVE_K:
            self._changed_at_s = output_time_s

    def take(self, worker: LearningWorker, tick: TickInputs, phase: CoolerPhase, flange_phase_rad: float,
             effect: np.ndarray, period_s: float) -> None:
        """A tick with the cooler's phase locked: its T2 reading to the learner, or a gap.

        Parameters
        ----------
        worker : LearningWorker
            The learner's thread.
        tick : TickInputs
        phase : CoolerPhase
            The cooler's phase as tracked at this tick.
        flange_phase_rad : float
            The cooler's phase at T2's reading (rad).
        effect : numpy.ndarray
            The effect on T2 of what the heater played last tick (K per harmonic).
        period_s : float
            The loop's period (s): a tick longer than 1.5 periods after the last is a gap.
        """
        if tick.dt_s > 1.5 * period_s:
            self._held_since_s = phase.time_s       # a gap: the loop held the heater off (a fault, start-up)
            self.unplayed.reset()
        if phase.time_s - self._held_since_s < SETTLE_S or tick.flange_time_s - self._changed_at_s < CHANGE_SETTLE_S:
            self.gap(worker)
        else:
            self._in_gap = False
            worker.reading(flange_phase_rad, tick.flange_K - self.unplayed.at(tick.flange_time_s), effect)


__all__ = ["CHANGE_SETTLE_ABOVE_K", "CHANGE_SETTLE_S", "ReadingFeed", "SETTLE_S"]
