"""The feedforward: a heater waveform locked to the cooler that cancels its line on the flange.

* the ``feedforward`` control term: :mod:`~cryod.control.feedforward.term`; its settings
  (:mod:`~cryod.control.feedforward.settings`), its record columns (:mod:`~cryod.control.feedforward.record_columns`);
  its states, the events between them and what it does in each (:mod:`~cryod.control.feedforward.state_machine`);
  what the heater plays (:mod:`~cryod.control.feedforward.played_waveform`) on the power it rides on
  (:mod:`~cryod.control.feedforward.power_levels`); the words of ``cryod ctl feedforward status``, from a
  snapshot (:mod:`~cryod.control.feedforward.status_text`);
* its learner, a Kalman filter of T2's part synchronous with the cooler
  (:mod:`~cryod.control.feedforward.synchronous_estimator`), on a worker thread
  (:mod:`~cryod.control.feedforward.learning_worker`), fed the readings it takes
  (:mod:`~cryod.control.feedforward.reading_feed`); a learning step as the worker computes it
  (:mod:`~cryod.control.feedforward.learning_step`) and as the loop's thread asks, takes and judges it
  (:mod:`~cryod.control.feedforward.learning_steps`);
* the plant at the cooler's harmonics: from the model (:mod:`~cryod.control.feedforward.harmonic_plant`),
  as learned (:mod:`~cryod.control.feedforward.plant_learner`, :mod:`~cryod.control.feedforward.plant_probe`),
  the learning step in its metric (:mod:`~cryod.control.feedforward.learned_projection`), the guard against
  a learning that diverges (:mod:`~cryod.control.feedforward.divergence_guard`) and the wait before it
  learns again (:mod:`~cryod.control.feedforward.divergence_retry`), the power the heater could
  not play (:mod:`~cryod.control.feedforward.unplayed_power`), what the learning says
  (:mod:`~cryod.control.feedforward.learning_report`);
* the physical limit: the best waveform within the heater's bounds
  (:mod:`~cryod.control.feedforward.bounded_waveform`), the limit, its sweeps and what would change it
  (:mod:`~cryod.control.feedforward.limit`), its range for an uncertain model
  (:mod:`~cryod.control.feedforward.limit_range`), from what was learned
  (:mod:`~cryod.control.feedforward.learned_limit`), followed at the setpoint in use
  (:mod:`~cryod.control.feedforward.limit_follower`), what binds it in the lab's words
  (:mod:`~cryod.control.feedforward.limit_binding`).

How it works and why, with the results: docs/explanation/feedforward.md. The term's names are also here, where the
control terms' table (:data:`cryod.control.terms.TERM_TYPES`) and users import them from.
"""

from cryod.control.feedforward.synchronous_estimator import SynchronousEstimator
from cryod.control.feedforward.settings import FeedforwardSettings
from cryod.control.feedforward.term import FeedforwardTerm

__all__ = ["FeedforwardSettings", "FeedforwardTerm", "SynchronousEstimator"]
