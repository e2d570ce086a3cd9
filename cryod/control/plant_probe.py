"""The probe: a small, bounded excitation at the harmonics whose plant the waveform's own changes do not tell.

The feedforward learns the plant at each harmonic from how T2 answers changes
of what the heater plays (:mod:`cryod.control.plant_learner`). The waveform
changes a lot at the fundamental (it fades in, it learns), but hardly at a
harmonic the line does not need, and not at all once it has converged: there
the plant stays unknown, or its knowledge fades as it may drift. The probe adds,
at each harmonic whose plant is known less well than ``precision`` (relative
standard deviation), a sinusoid that moves T2 by about ``amplitude_K`` and
turns by a quarter period at every learning step, a sequence fixed in advance
(independent of the readings, so what T2 does in answer tells the plant without
the bias of changes the noise decided).

Bounded three ways: it takes at most ``room_share`` of the heater's room around
the power the waveform rides on (the waveform is projected within what is left),
it stops at a harmonic once the plant there is known to ``precision``, and a
burst at a harmonic ends after ``longest_s`` of playing even if it is not (a
plant too weak for the probe to tell within its bounds: said in the status); it
comes back when the plant's spread has grown to :data:`RESUME_FACTOR` times
what it was left at. Its cost, T2's answer to it, ``|H_n p_n|`` through the
learned plant, is reported.

Examples
--------
>>> import numpy as np
>>> from cryod.control.plant_learner import LearnedPlant
>>> plant = LearnedPlant.from_model(np.array([7.36e-3 * np.exp(-2.0j), 4.06e-3 * np.exp(-2.5j)]))
>>> settings = ProbeSettings(amplitude_K=50e-6)
>>> state, probe = next_probe(ProbeState.start(2), plant, room_w=0.2, interval_s=2.0, settings=settings)
>>> np.round(np.abs(probe) * 1e3, 1)                 # mW: 50 uK through each harmonic's plant
array([ 6.8, 12.3])
>>> round(probe_cost_K(probe, plant.plant) * 1e6, 1)  # T2's answer, harmonics together (uK)
70.7
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from cryod.control.plant_learner import LearnedPlant

#: The probe turns by this at every learning step.
PHASE_STEP_RAD = 0.5 * math.pi
#: Harmonic n's probe starts at n times this, so the harmonics' peaks do not line up.
PHASE_OFFSET_RAD = math.pi * (3.0 - math.sqrt(5.0))
#: The probe comes back at a harmonic when the plant's spread has grown to this times what it was left at.
RESUME_FACTOR = 2.0


@dataclass(frozen=True)
class ProbeSettings:
    """How much the probe may move T2 and for what.

    Attributes
    ----------
    amplitude_K : float
        T2's answer at each harmonic probed (K; 0: no probe).
    precision : float
        Relative standard deviation of the plant at which probing a harmonic stops.
    longest_s : float
        Longest burst at one harmonic (s of playing).
    room_share : float
        Largest share of the heater's room (below and above the power the waveform rides on) it takes.
    """

    amplitude_K: float = 50e-6
    precision: float = 0.025
    longest_s: float = 300.0
    room_share: float = 0.25


@dataclass(frozen=True)
class ProbeState:
    """Per harmonic: probing or not, how long this burst has played (s), the spread it was left at (NaN: reached
    the precision); and the steps taken (the probe's turn)."""

    probing: tuple[bool, ...]
    played_s: tuple[float, ...]
    left_at: tuple[float, ...]
    steps: int = 0

    @classmethod
    def start(cls, harmonics: int) -> "ProbeState":
        """Nothing probed yet: every harmonic starts probing once it can."""
        return cls((True,) * harmonics, (0.0,) * harmonics, (math.nan,) * harmonics)

    def given_up(self) -> list[int]:
        """Harmonics (from 1) whose last burst ended before the plant was known to the precision."""
        return [index + 1 for index, (on, left) in enumerate(zip(self.probing, self.left_at))
                if not on and math.isfinite(left)]


def next_probe(state: ProbeState, plant: LearnedPlant, room_w: float, interval_s: float,
               settings: ProbeSettings) -> tuple[ProbeState, np.ndarray]:
    """The probe for the coming learning interval, and the state after deciding it.

    Parameters
    ----------
    state : ProbeState
    plant : LearnedPlant
        What is known of the plant now.
    room_w : float
        The heater's room around the power the waveform rides on: the lesser of the distances to its bounds (W).
    interval_s : float
        The learning interval: how long this probe plays (s).
    settings : ProbeSettings

    Returns
    -------
    (ProbeState, numpy.ndarray)
        The new state and the probe's complex amplitudes (W) per harmonic.
    """
    spread = plant.relative_spread
    probing, played, left_at = list(state.probing), list(state.played_s), list(state.left_at)
    for index in range(plant.harmonics):
        if probing[index]:
            if spread[index] < settings.precision:
                probing[index], left_at[index] = False, math.nan
            elif played[index] >= settings.longest_s:
                probing[index], left_at[index] = False, float(spread[index])
        else:
            reference = left_at[index] if math.isfinite(left_at[index]) else settings.precision
            if spread[index] > RESUME_FACTOR * reference:
                probing[index], played[index] = True, 0.0
    on = np.array(probing) & (settings.amplitude_K > 0.0)
    amplitude = np.where(on, settings.amplitude_K / np.maximum(np.abs(plant.plant), 1e-12), 0.0)
    total = float(np.sum(amplitude))
    budget = settings.room_share * max(room_w, 0.0)
    if total > budget:
        amplitude *= budget / total if total > 0.0 else 0.0
    orders = np.arange(1, plant.harmonics + 1)
    probe = amplitude * np.exp(1j * (state.steps * PHASE_STEP_RAD + orders * PHASE_OFFSET_RAD))
    played = [seconds + (interval_s if amplitude[index] > 0.0 else 0.0) for index, seconds in enumerate(played)]
    return replace(state, probing=tuple(probing), played_s=tuple(played), left_at=tuple(left_at),
                   steps=state.steps + 1), probe


def probe_cost_K(probe: np.ndarray, plant: np.ndarray) -> float:
    """T2's answer to the probe, harmonics together (K, amplitude: the root of the sum of squares)."""
    return float(np.sqrt(np.sum(np.abs(plant * probe) ** 2)))


__all__ = ["PHASE_STEP_RAD", "ProbeSettings", "ProbeState", "RESUME_FACTOR", "next_probe", "probe_cost_K"]
