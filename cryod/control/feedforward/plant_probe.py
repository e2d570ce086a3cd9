"""The probe: a small, bounded excitation at the harmonics whose plant the waveform's own changes do not tell.

Why, and how well it works: docs/explanation/feedforward.md ("The probe").

The feedforward learns the plant at each harmonic from how T2 answers changes
of what the heater plays (:mod:`cryod.control.feedforward.plant_learner`). The waveform
changes a lot at the fundamental (it fades in, it learns), but hardly at a
harmonic the line does not need, and not at all once it has converged: there
the plant stays unknown, or its knowledge fades as it may drift. The probe adds,
at each harmonic whose plant is known less well than ``precision`` (relative
standard deviation), a sinusoid that moves T2 by about ``amplitude_K`` and
turns by a quarter period at every learning step, a sequence fixed in advance
(independent of the readings, so what T2 does in answer tells the plant without
the bias of changes the noise decided).

One harmonic at a time, the lowest first (the line's, which the waveform
waits for): what the probe tells grows with the square of its amplitude and
what it costs (its peak, the room it takes from the waveform) with the
amplitude, so the whole room for one harmonic, then the next, learns them
all sooner than a share each at once.

While T2 is still on its way to a new setpoint, what the probe costs does not
count: it may then be ``approach_gain`` times larger and take
``approach_room_share`` of the room, so that most of the plant is known by the
time T2 arrives.

Bounded three ways: it takes at most ``room_share`` of the heater's room around
the power the waveform rides on (the waveform is projected within what is left),
it stops at a harmonic once the plant there is known to ``precision``, and a
burst at a harmonic ends after ``longest_s`` of playing even if it is not; a
harmonic where a whole burst could not bring the plant's spread to the
precision, or to :data:`WORTH` of what it is (a plant too weak for what the
room allows now), waits while the next one is probed. It comes back when the plant's spread has grown to :data:`RESUME_FACTOR` times
what it was left at. Its cost, T2's answer to it, ``|H_n p_n|`` through the
learned plant, is reported.

Examples
--------
>>> import numpy as np
>>> from cryod.control.feedforward.plant_learner import MODEL_ERROR, LearnedPlant
>>> plant = LearnedPlant.from_model(np.array([7.36e-3 * np.exp(-2.0j), 4.06e-3 * np.exp(-2.5j)]))
>>> settings = ProbeSettings(amplitude_K=50e-6)
>>> state, probe = next_probe(ProbeState.start(2), plant, 0.2, 2.0, settings)
>>> np.round(np.abs(probe) * 1e3, 1)                 # mW: the line first, 50 µK through its plant
array([6.8, 0. ])
>>> learned = LearnedPlant(plant.model, plant.correction, np.array([np.eye(2) * 1e-4, np.eye(2)]))
>>> state, probe = next_probe(state, learned, 0.2, 2.0, settings)
>>> np.round(np.abs(probe) * 1e3, 1)                 # the line known to 1.4 %: the second harmonic
array([ 0. , 12.3])
>>> round(probe_cost_K(probe, learned.plant) * 1e6, 1)   # T2's answer, harmonics together (µK)
50.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from cryod.control.feedforward.plant_learner import MODEL_ERROR, LearnedPlant

#: The probe turns by this at every learning step.
PHASE_STEP_RAD = 0.5 * math.pi
#: Harmonic n's probe starts at n times this, so the harmonics' peaks do not line up.
PHASE_OFFSET_RAD = math.pi * (3.0 - math.sqrt(5.0))
#: The probe comes back at a harmonic when the plant's spread has grown to this times what it was left at.
RESUME_FACTOR = 2.0
#: A burst is begun where it would bring the spread below this fraction of what it is (or to the precision).
WORTH = 0.7


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
        Longest burst at one harmonic (s of playing; the harmonics above it wait for it).
    room_share : float
        Largest share of the heater's room (below and above the power the waveform rides on) it takes.
    noise_K : float
        T2's reading noise (K rms): a burst that could not tell the plant is not tried.
    readings_per_s : float
    approach_gain : float
        While T2 is on its way to the setpoint, the probe moves T2 this many times more (and may take
        ``approach_room_share`` of the room): what it costs then does not count, and the plant is
        learned sooner.
    approach_room_share : float
    """

    amplitude_K: float = 50e-6
    precision: float = 0.03
    longest_s: float = 60.0
    room_share: float = 0.15
    noise_K: float = 20e-6
    readings_per_s: float = 12.5
    approach_gain: float = 3.0
    approach_room_share: float = 0.4


@dataclass(frozen=True)
class ProbeState:
    """Per harmonic: probing (or waiting to) or not, how long this burst has played (s), the spread it was left at
    (NaN: reached the precision); and the steps taken (the probe's turn)."""

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
               settings: ProbeSettings, approaching: bool = False) -> tuple[ProbeState, np.ndarray]:
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
    approaching : bool
        T2 is still on its way to the setpoint: the probe may be larger.

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
    if approaching:
        settings = replace(settings, amplitude_K=settings.approach_gain * settings.amplitude_K,
                           room_share=settings.approach_room_share)
    budget = settings.room_share * max(room_w, 0.0)
    gain = np.maximum(np.abs(plant.plant), 1e-12)
    amplitude = np.zeros(plant.harmonics)
    for index in range(plant.harmonics):               # one harmonic at a time, the lowest worth it now first
        if not probing[index] or settings.amplitude_K <= 0.0:
            continue
        power = min(settings.amplitude_K / gain[index], budget)
        if power <= 0.0:
            break                                       # no room now: wait
        # a burst once begun goes on; one not begun only where it could tell the plant
        if played[index] > 0.0 or _worth_it(spread[index], gain[index] * power, settings):
            amplitude[index] = power
            break
    orders = np.arange(1, plant.harmonics + 1)
    probe = amplitude * np.exp(1j * (state.steps * PHASE_STEP_RAD + orders * PHASE_OFFSET_RAD))
    played = [seconds + (interval_s if amplitude[index] > 0.0 else 0.0) for index, seconds in enumerate(played)]
    return replace(state, probing=tuple(probing), played_s=tuple(played), left_at=tuple(left_at),
                   steps=state.steps + 1), probe


def _worth_it(spread: float, signal_K: float, settings: ProbeSettings) -> bool:
    """Whether a whole burst would bring the plant's spread to the precision, or to a usable value from an unusable
    one, or to :data:`WORTH` of what it is."""
    after = _spread_after(spread, signal_K, settings.longest_s, settings)
    return after <= settings.precision or (after < MODEL_ERROR <= spread) or after <= WORTH * spread


def _spread_after(spread: float, signal_K: float, seconds: float, settings: ProbeSettings) -> float:
    """The plant's relative spread expected after ``seconds`` of a probe that moves T2 by ``signal_K`` against
    readings with noise ``settings.noise_K`` (a least-squares fit of a turning phasor)."""
    readings = max(seconds, 0.0) * settings.readings_per_s
    information = readings * signal_K ** 2 / (4.0 * settings.noise_K ** 2)
    return 1.0 / math.sqrt(1.0 / max(spread, 1e-9) ** 2 + information)


def probe_cost_K(probe: np.ndarray, plant: np.ndarray) -> float:
    """T2's answer to the probe, harmonics together (K, amplitude: the root of the sum of squares)."""
    return float(np.sqrt(np.sum(np.abs(plant * probe) ** 2)))


__all__ = ["PHASE_STEP_RAD", "ProbeSettings", "ProbeState", "RESUME_FACTOR", "next_probe", "probe_cost_K"]
