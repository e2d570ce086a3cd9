"""The feedforward's learner: a Kalman filter of T2's part synchronous with the cooler.

It splits that part into the cooler's line and the waveform's effect through
the controller's model, with a correction of the model's plant at each harmonic
learned from how T2 answers what the heater plays (:class:`SynchronousEstimator`).
The feedforward feeds it on a worker thread
(:mod:`cryod.control.feedforward.learning_worker`); what it learned of the
plant, with its covariance, is read as a
:class:`~cryod.control.feedforward.plant_learner.LearnedPlant`. Why, and how
well it works: docs/explanation/feedforward.md ("How it works", "The plant, with its
uncertainty").

The filter is written out here rather than taken from a library (filterpy,
statsmodels' state-space models). Its update is a few lines of numpy; what
makes it this estimator is around the update: the regressors built at each
reading from the cooler's phase and the waveform's modelled effect, the second
differences that remove T2's slow part, a batch of them per update, a plant
correction that drifts in proportion to its own size, the learned plant kept
when the controller's model changes and forgotten on demand, and its
covariance read back per harmonic as the readings give it. A general filter
would hold the state and the matrices and leave all of that here; statsmodels
fits a record afterwards, while this one takes the readings one at a time as
the loop makes them.

Examples
--------
>>> import numpy as np
>>> estimator = SynchronousEstimator(1)
>>> for k in range(500):
...     phase = 10.83 * 0.08 * k
...     estimator.add(phase, 5.0 + 1e-3 * np.cos(phase + 0.5), np.zeros(1, dtype=complex))
>>> estimator.ready, round(abs(complex(estimator.line[0])) * 1e3, 3), round(float(np.angle(estimator.line[0])), 2)
(True, 1.0, 0.5)
"""

from __future__ import annotations

import numpy as np

from cryod.control.feedforward.plant_learner import PRIOR_SPREAD, LearnedPlant

#: Loop period the filter assumes when not told (s).
DEFAULT_PERIOD_S = 0.08
#: Second differences the estimator takes into one update of its filter.
BATCH = 4


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
    a percent changes T2's line by a percent), the plant's correction by
    :data:`CORRECTION_DRIFT_PER_HOUR` of itself per hour. ``k`` is learned only
    from readings where what the heater plays changes (the waveform coming in
    and learning, the probe) and is kept between them; it starts at 1 with a
    spread of ``correction_spread`` on each part, so any phase is possible.
    What is learned, with its covariance, is read as a
    :class:`~cryod.control.feedforward.plant_learner.LearnedPlant`, which decides where it
    is known well enough to be used.

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
        Prior spread of each part of ``k`` around 1.
    line_drift_K : float
        How much the line may change over ``memory_s`` (K).
    """

    #: The correction of the plant may drift by about this fraction of itself per hour.
    CORRECTION_DRIFT_PER_HOUR = 0.02

    def __init__(self, harmonics: int, noise_K: float = 20e-6, memory_s: float = 60.0,
                 period_s: float = DEFAULT_PERIOD_S, correction_spread: float = PRIOR_SPREAD,
                 line_drift_K: float = 20e-6):
        self.harmonics = harmonics
        self.memory_s = memory_s
        self.period_s = period_s
        self.orders = np.arange(1, harmonics + 1)
        self.size = 4 * harmonics
        n = 2 * harmonics
        line_scale = 3e-3           # K: a line of mK at most
        steps = memory_s / period_s
        self._correction_drift = self.CORRECTION_DRIFT_PER_HOUR ** 2 * period_s / 3600.0
        self._process = np.concatenate([np.full(n, line_drift_K ** 2 / steps), np.full(n, self._correction_drift)])
        self._line_variance = line_scale ** 2
        self._correction_variance = correction_spread ** 2
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

    def _blocks(self, first: int) -> np.ndarray:
        """(harmonics, 2, 2): the covariance of the real and imaginary parts of the state from ``first`` on."""
        n = self.harmonics
        real, imaginary = np.arange(first, first + n), np.arange(first + n, first + 2 * n)
        c = self.covariance
        return np.stack([np.stack([c[real, real], c[real, imaginary]], axis=-1),
                         np.stack([c[imaginary, real], c[imaginary, imaginary]], axis=-1)], axis=-2)

    @property
    def correction_covariance(self) -> np.ndarray:
        """(harmonics, 2, 2): the covariance of (Re k_n, Im k_n), as the filter states it."""
        return self._blocks(2 * self.harmonics)

    def _as_the_readings_give(self, covariance: np.ndarray, prior_variance: float,
                              frequency_rad_s: float | None) -> np.ndarray:
        """A block covariance as the readings give it (see :meth:`learned_plant`): the information the readings
        brought corrected by the second differences' misstatement at each harmonic; the prior's kept."""
        if frequency_rad_s is None:
            return covariance
        gain = (2.0 - 2.0 * np.cos(self.orders * frequency_rad_s * self.period_s)) ** 2 / 6.0
        prior = np.eye(2) / prior_variance
        information = np.linalg.inv(covariance) - prior
        information = 0.5 * (information + np.swapaxes(information, 1, 2))
        values, vectors = np.linalg.eigh(information)
        information = np.einsum("nij,nj,nkj->nik", vectors, np.maximum(values, 0.0), vectors)
        return np.linalg.inv(prior + information / np.maximum(gain, 1e-3)[:, None, None])

    def learned_plant(self, model_plant: np.ndarray, frequency_rad_s: float | None = None) -> LearnedPlant:
        """What is learned of the plant, against the model's ``model_plant`` (K/W per harmonic).

        The filter takes the second differences as independent, each with six times the readings'
        noise variance; they are not (consecutive ones share readings), and what that misstates depends
        on the harmonic: a second difference passes harmonic n by ``2 - 2 cos(n omega T)`` and its noise
        by the same at that frequency, so the estimate is as good as a fit to the readings themselves,
        while the filter's covariance says it is ``(2 - 2 cos(n omega T))**2 / 6`` times as good (12
        times worse at the fundamental, 2.3 times better at the third harmonic, at 80 ms). The
        information the readings brought is corrected by that factor (``frequency_rad_s``, the cooler's;
        none: as the filter has it); the prior's is kept.
        """
        covariance = self._as_the_readings_give(self.correction_covariance, self._correction_variance,
                                                frequency_rad_s)
        return LearnedPlant(np.asarray(model_plant, dtype=complex), self.raw_correction.copy(), covariance)

    @property
    def correction(self) -> np.ndarray:
        """The plant correction at each harmonic where the readings tell it better than the model's
        assumed error (:data:`~cryod.control.feedforward.plant_learner.MODEL_ERROR`), else 1: the model's."""
        return np.where(self.learned_plant(np.ones(self.harmonics)).learned, self.raw_correction, 1.0)

    def reset_correction(self) -> None:
        """Forget what was learned of the plant: the model's again, with the prior's spread."""
        n = self.harmonics
        self.state[2 * n:3 * n], self.state[3 * n:] = 1.0, 0.0
        self.covariance[2 * n:, :] = 0.0
        self.covariance[:, 2 * n:] = 0.0
        self._covariance_diagonal[2 * n:] = self._correction_variance

    def rescale_correction(self, factor: np.ndarray) -> None:
        """The model's plant changed by ``1 / factor`` at each harmonic: keep the learned plant (``k *= factor``)."""
        n = self.harmonics
        factor = np.asarray(factor, dtype=complex)
        transform = np.eye(self.size)
        index = np.arange(n)
        real, imaginary = 2 * n + index, 3 * n + index
        transform[real, real], transform[real, imaginary] = factor.real, -factor.imag
        transform[imaginary, real], transform[imaginary, imaginary] = factor.imag, factor.real
        self.state = transform @ self.state
        self.covariance[:] = transform @ self.covariance @ transform.T

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
        n = self.harmonics
        size = np.maximum(np.abs(self.raw_correction), 0.05) ** 2      # the correction drifts relative to itself
        self._process[2 * n:3 * n] = self._process[3 * n:] = self._correction_drift * size
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


__all__ = ["BATCH", "DEFAULT_PERIOD_S", "SynchronousEstimator"]
