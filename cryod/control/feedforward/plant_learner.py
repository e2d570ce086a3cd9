"""The plant the feedforward learns: how the heater reaches T2's readings at each harmonic, and how well it is known.

Why, and how well it works: docs/explanation/feedforward.md ("The plant, with its uncertainty").

The feedforward's estimator (:class:`cryod.control.feedforward.SynchronousEstimator`)
learns, at each harmonic n of the cooler, a complex correction ``k_n`` of the
controller model's plant ``H_n`` (from a waveform coefficient to T2's readings,
as the loop samples them: :func:`cryod.control.feedforward.harmonic_plant.plant_at_harmonics`)
with its covariance, from how T2 answers the waveform's changes and the probe's
(:mod:`cryod.control.feedforward.plant_probe`). :class:`LearnedPlant` turns that into the
plant the feedforward uses, over the full +-180 degrees:

* the plant ``k_n H_n`` with the correction as estimated is the best estimate
  there is (the model's ``H_n`` before the readings say anything): the waveform
  is measured in it at every harmonic;
* the waveform aims at the line only at a harmonic whose correction is known to
  better than the model's assumed error (:data:`MODEL_ERROR`, relative standard
  deviation), and was at the step before with a value that agrees within
  :data:`AGREEMENT_SIGMAS` (a first estimate from a few seconds of readings
  states a spread it does not have yet): there the plant is *learned*; a step
  through a plant off by more than 90 degrees would make the line grow;
* where the learned plant differs from the model by more than its uncertainty
  (and by more than matters, :data:`DIFFERENCE_GAIN`, :data:`DIFFERENCE_PHASE_DEG`),
  it says so in words, for the status and the journal.

Examples
--------
>>> import numpy as np
>>> model = np.array([7.36e-3 * np.exp(-2.0j)])
>>> learned = LearnedPlant(model, np.array([0.62 * np.exp(-1.22j)]), np.array([np.eye(2) * 1e-4]))
>>> bool(learned.learned[0]), round(float(abs(learned.plant[0])) * 1e3, 2)
(True, 4.56)
>>> print(learned.differences_said())
the heater reaches T2 1.6x weaker and 70 degrees later than the model at the line: re-commission with cryod identify --acquire
>>> print(LearnedPlant.from_model(model).difference())
None
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

#: The controller's model is taken to be right to within this at each harmonic (relative standard deviation of the
#: learned correction): the learned plant is used once it is known better (30 %: 17 degrees).
MODEL_ERROR = 0.3
#: A learned value differs from the model when it is further from it than this many standard deviations ...
DIFFERENCE_SIGMAS = 3.0
#: ... and by more than this in gain (relative) or phase (degrees): what changes the waveform noticeably.
DIFFERENCE_GAIN = 0.05
DIFFERENCE_PHASE_DEG = 5.0
#: Prior standard deviation of each part (real, imaginary) of the correction: any phase is possible.
PRIOR_SPREAD = 1.0
#: A correction is confirmed when it agrees with the one at the step before within this many standard deviations.
AGREEMENT_SIGMAS = 3.0
#: What to do about a plant that differs from the model.
RECOMMISSION = "re-commission with cryod identify --acquire"


@dataclass(frozen=True, eq=False)
class LearnedPlant:
    """The plant at each harmonic: the model's, the correction learned, its covariance.

    Parameters
    ----------
    model : numpy.ndarray
        ``H_n`` of the controller's model (K/W, complex), n = 1..N.
    correction : numpy.ndarray
        ``k_n`` as estimated (complex): the cryostat's plant is ``k_n H_n``.
    covariance : numpy.ndarray
        (N, 2, 2): the covariance of (Re k_n, Im k_n).
    confirmed : numpy.ndarray, optional
        Per harmonic, whether the correction was known well enough at the step before too, and agrees with it
        (:meth:`confirmed_against`); None: taken as confirmed.
    """

    model: np.ndarray
    correction: np.ndarray
    covariance: np.ndarray
    confirmed: np.ndarray | None = None

    def confirmed_against(self, before: "LearnedPlant | None") -> "LearnedPlant":
        """This, with each harmonic confirmed where ``before`` (the step before's) was known well enough too and
        agrees with this within :data:`AGREEMENT_SIGMAS` standard deviations, or was confirmed already."""
        if before is None or len(before.model) != len(self.model):
            return dataclasses.replace(self, confirmed=np.zeros(len(self.model), dtype=bool))
        spread = np.maximum(self.relative_spread, before.relative_spread) * np.abs(self.correction)
        agree = np.abs(self.correction - before.correction) <= AGREEMENT_SIGMAS * np.sqrt(2.0) * spread
        known_before = before.relative_spread < MODEL_ERROR
        confirmed = known_before & (agree | before.learned)
        return dataclasses.replace(self, confirmed=confirmed)

    @classmethod
    def from_model(cls, model: np.ndarray) -> "LearnedPlant":
        """Nothing learned yet: the model's plant with the prior's spread."""
        count = len(model)
        return cls(np.asarray(model, dtype=complex), np.ones(count, dtype=complex),
                   np.tile(np.eye(2) * PRIOR_SPREAD ** 2, (count, 1, 1)))

    @property
    def harmonics(self) -> int:
        return len(self.model)

    @cached_property
    def gain_ratio(self) -> np.ndarray:
        """|k_n|: the learned plant's gain over the model's."""
        return np.abs(self.correction)

    @cached_property
    def phase_deg(self) -> np.ndarray:
        """arg k_n in degrees: positive where the learned plant leads the model, negative where it lags."""
        return np.degrees(np.angle(self.correction))

    def _along(self, direction: np.ndarray) -> np.ndarray:
        """Standard deviation of the correction along a unit direction (Re, Im) per harmonic."""
        vector = np.stack([direction.real, direction.imag], axis=-1)
        return np.sqrt(np.maximum(np.einsum("ni,nij,nj->n", vector, self.covariance, vector), 0.0))

    @cached_property
    def gain_spread(self) -> np.ndarray:
        """Relative standard deviation of the learned gain, |k_n|'s over |k_n|."""
        unit = np.exp(1j * np.angle(self.correction))
        return self._along(unit) / np.maximum(self.gain_ratio, 1e-12)

    @cached_property
    def phase_spread_deg(self) -> np.ndarray:
        """Standard deviation of the learned phase (degrees)."""
        unit = 1j * np.exp(1j * np.angle(self.correction))
        return np.degrees(self._along(unit) / np.maximum(self.gain_ratio, 1e-12))

    @cached_property
    def relative_spread(self) -> np.ndarray:
        """Standard deviation of k_n (both parts) over |k_n|."""
        total = np.sqrt(np.maximum(self.covariance[:, 0, 0] + self.covariance[:, 1, 1], 0.0))
        return total / np.maximum(self.gain_ratio, 1e-12)

    @cached_property
    def learned(self) -> np.ndarray:
        """Where the correction is known better than the model's assumed error, and confirmed (bool per harmonic)."""
        known = self.relative_spread < MODEL_ERROR
        return known if self.confirmed is None else known & self.confirmed

    @cached_property
    def plant(self) -> np.ndarray:
        """The best estimate of the plant, ``k_n H_n`` (K/W): the model's where nothing is learned yet (``k_n`` is
        1 there), closer to what the readings say the more they say. The waveform is measured in it (the metric of
        the projection onto the heater's bounds, the probe's size) at every harmonic; it aims at the line only
        where the plant is :attr:`learned`."""
        return self.model * self.correction

    @cached_property
    def source(self) -> str:
        """``"learned"`` when the plant at the fundamental is, else ``"model"``."""
        return "learned" if self.learned[0] else "model"

    def prepared(self) -> "LearnedPlant":
        """This, with everything derived from it computed (on the learning's thread, not the loop's)."""
        for index in range(self.harmonics):
            self.differs(index)
        return self

    def differs(self, index: int = 0) -> tuple[bool, bool]:
        """Whether the learned gain and phase at harmonic ``index + 1`` differ from the model's (beyond the
        uncertainty and beyond what matters)."""
        return self._differing[index]

    @cached_property
    def _differing(self) -> list[tuple[bool, bool]]:
        ratio, gain_sigma = self.gain_ratio, self.gain_spread * self.gain_ratio
        phase, phase_sigma = self.phase_deg, self.phase_spread_deg
        gain = np.abs(ratio - 1.0) > np.maximum(DIFFERENCE_SIGMAS * gain_sigma, DIFFERENCE_GAIN)
        angle = np.abs(phase) > np.maximum(DIFFERENCE_SIGMAS * phase_sigma, DIFFERENCE_PHASE_DEG)
        return [(bool(g and known), bool(a and known)) for g, a, known in zip(gain, angle, self.learned)]

    def difference(self, index: int = 0) -> str | None:
        """In words, how the learned plant at harmonic ``index + 1`` differs from the model, or None."""
        gain, angle = self.differs(index)
        if not (gain or angle):
            return None
        ratio = float(self.gain_ratio[index])
        parts = []
        if gain:
            parts.append(f"{1.0 / ratio:.1f}x weaker" if ratio < 1.0 else f"{ratio:.1f}x stronger")
        if angle:
            phase = float(self.phase_deg[index])
            parts.append(f"{abs(phase):.0f} degrees {'later' if phase < 0 else 'earlier'}")
        where = "at the line" if index == 0 else f"at harmonic {index + 1}"
        return f"the heater reaches T2 {' and '.join(parts)} than the model {where}"

    def differences(self) -> list[str]:
        """:meth:`difference` at every harmonic where there is one."""
        return [text for text in (self.difference(index) for index in range(self.harmonics)) if text]

    def differences_said(self) -> str | None:
        """All the differences in one sentence, with what to do (None where the plant agrees with the model)."""
        said = self.differences()
        if not said:
            return None
        prefix = "the heater reaches T2 "
        rest = [text[len(prefix):].replace(" than the model", "") for text in said[1:]]
        return "; ".join([said[0], *rest]) + f": {RECOMMISSION}"

    def describe(self) -> str:
        """One line per harmonic: gain and phase against the model, their spread, learned or the model's."""
        lines = []
        for index in range(self.harmonics):
            plant = self.plant[index]
            against = (f"{self.gain_ratio[index]:.3f} x the model's +-{100 * self.gain_spread[index]:.1f} %, "
                       f"{self.phase_deg[index]:+.1f} +-{self.phase_spread_deg[index]:.1f} deg")
            state = (f"learned: {against}" if self.learned[index] else
                     "the model's: nothing learned yet" if self.relative_spread[index] >= PRIOR_SPREAD else
                     f"known to {100 * self.relative_spread[index]:.0f} % only, {against}: the waveform does not "
                     f"aim at the line there")
            lines.append(f"  harmonic {index + 1}: {1e3 * abs(plant):.3f} mK/W, {math.degrees(np.angle(plant)):+.0f} deg "
                         f"({state})")
        return "\n".join(lines)

    def summary(self) -> list[dict]:
        """Per harmonic, as plain JSON-ready values."""
        return [{"harmonic": index + 1, "learned": bool(self.learned[index]),
                 "gain_ratio": float(self.gain_ratio[index]), "gain_spread": float(self.gain_spread[index]),
                 "phase_deg": float(self.phase_deg[index]), "phase_spread_deg": float(self.phase_spread_deg[index]),
                 "plant_K_per_W": [float(self.plant[index].real), float(self.plant[index].imag)],
                 "model_K_per_W": [float(self.model[index].real), float(self.model[index].imag)]}
                for index in range(self.harmonics)]

    def record_text(self) -> str:
        """The learned plant in one line for the data log's event lines."""
        return "; ".join(
            f"harmonic {index + 1}: " + (f"{self.gain_ratio[index]:.4f} +-{self.gain_spread[index] * self.gain_ratio[index]:.4f} x, "
                                         f"{self.phase_deg[index]:+.2f} +-{self.phase_spread_deg[index]:.2f} deg"
                                         if self.learned[index] else "model")
            for index in range(self.harmonics))


__all__ = ["AGREEMENT_SIGMAS", "DIFFERENCE_GAIN", "DIFFERENCE_PHASE_DEG", "DIFFERENCE_SIGMAS", "LearnedPlant",
           "MODEL_ERROR", "PRIOR_SPREAD", "RECOMMISSION"]
