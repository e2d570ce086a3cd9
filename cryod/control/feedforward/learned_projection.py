"""A learning step of the waveform, projected onto the heater's bounds in the learned plant's metric.

Why, and how well it works: docs/explanation/feedforward.md ("The projection in the learned metric").

Every learning interval the waveform's coefficients step toward cancelling the
estimated line, ``u_n <- u_n + gain (-L_n / H_n - u_n)``, at each harmonic whose
plant is learned (:class:`cryod.control.feedforward.plant_learner.LearnedPlant`), and the
result is replaced by the waveform the heater can play that is closest to it
in T2's terms, ``min sum_n |H_n (u_n - stepped_n)|**2`` with the power the
waveform rides on plus the waveform within the bounds at every phase. In the
metric of the cryostat's own plant, the fixed point of step and projection is
the constrained optimum of that cryostat, the physical limit
(:mod:`cryod.control.feedforward.limit`); in the model's metric it would be
the model's optimum, which can leave much more on a cryostat whose plant
differs (at 6 K the fundamental needed sits within a few mW of both bounds).
At harmonics whose plant is not learned the step aims at nothing (their target
is 0: a step through a plant off by more than 90 degrees would make the line
grow) and the metric is the plant as estimated so far (the model's before
anything is known); the projection may still put content there where that lets
the learned harmonics come closer to their targets within the bounds (the
clipped pulse at 5 K is made of them), and its changes teach the plant there.

Examples
--------
>>> import numpy as np
>>> from cryod.control.feedforward.plant_learner import LearnedPlant
>>> plant = LearnedPlant(np.array([7.36e-3 * np.exp(-2.0j)]), np.array([0.5 + 0j]), np.array([np.eye(2) * 1e-4]))
>>> line = np.array([1.73e-3 + 0j])
>>> step = learning_step(np.zeros(1, dtype=complex), line, plant, gain=1.0, base_w=0.26, low_w=0.0, high_w=0.5)
>>> round(float(abs(step[0])), 3)     # 1.73 mK through 3.68 mK/W needs 470 mW: 240 mW fit below 500 mW
0.24
"""

from __future__ import annotations

import numpy as np

from cryod.control.feedforward.bounded_waveform import best_bounded_waveform
from cryod.control.feedforward.plant_learner import LearnedPlant


def learning_step(coefficients: np.ndarray, line: np.ndarray, plant: LearnedPlant, gain: float, base_w: float,
                  low_w: float, high_w: float, phase_points: int = 48) -> np.ndarray:
    """The waveform after one learning step (W, complex per harmonic).

    Parameters
    ----------
    coefficients : numpy.ndarray
        The waveform now, ``u_n`` (W).
    line : numpy.ndarray
        The estimated line on T2, ``L_n`` (K).
    plant : LearnedPlant
    gain : float
        Fraction of the way to cancelling the line (0 to 1).
    base_w : float
        The power the waveform rides on (W).
    low_w, high_w : float
        Bounds for the power plus the waveform (W).
    phase_points : int
        Phases at which the bounds are imposed.

    Returns
    -------
    numpy.ndarray
        The new coefficients (none while no harmonic's plant is learned).
    """
    use = plant.learned
    if not use.any():
        return np.zeros(plant.harmonics, dtype=complex)
    response = plant.plant
    target = np.zeros(plant.harmonics, dtype=complex)
    target[use] = coefficients[use] + gain * (-line[use] / response[use] - coefficients[use])
    return best_bounded_waveform(-response * target, response, base_w, low_w, high_w, phase_points=phase_points)


__all__ = ["learning_step"]
