"""What the heater plays for the feedforward: the waveform, the probe with it, and what T2's readings answer.

The waveform is ``Re(sum_n u_n exp(j n phase))`` (harmonics 1 to N, no mean), evaluated at the
cooler's phase at the middle of the coming hold, and the probe (:mod:`cryod.control.feedforward.plant_probe`)
is played with it. T2's reading at a tick answers what the heater played the tick before (its
effect on T2 through the controller's model: :meth:`PlayedWaveform.effect`): a new waveform taken
at a tick's start is played from that tick's output on, and until then the readings are still
the old one's answer.

Where the waveform changes, the tick it changes in adds the energy the change would otherwise
take or give (:meth:`PlayedWaveform.energy_kept`): a held waveform delivers, summed over the ticks,
a bounded oscillation plus a constant, and the constant moves with the phase the change falls at.
docs/explanation/feedforward.md ("No kicks"). The fade that takes the waveform in and out is :func:`faded`.

Examples
--------
>>> import cmath
>>> waveform = PlayedWaveform(2)
>>> waveform.set(np.array([0.1, 0.02j]), np.zeros(2))
>>> round(waveform.value(cmath.exp(0.5j)), 6)             # W at phase 0.5 rad
0.070929
>>> waveform.changed, round(float(waveform.energy_kept(cmath.exp(0.5j), 10.83 * 0.08)), 6)
(True, 0.020957)
>>> waveform.heard_now()
>>> waveform.changed
False
"""

from __future__ import annotations

import cmath

import numpy as np


def harmonic_sum(phasors, rotor: complex) -> float:
    """``Re sum_n p_n rotor^n`` (n from 1) for plain complex ``phasors`` (a numpy scalar per term is slow)."""
    value, power = 0.0, 1.0 + 0j
    for phasor in phasors:
        power *= rotor
        value += (phasor * power).real
    return value


def faded(scale: float, target: float, dt_s: float, fade_time_s: float) -> float:
    """The fade ``scale`` (0 to 1) moved ``dt_s`` toward ``target`` (0 or 1), over ``fade_time_s`` for the whole way."""
    step = dt_s / fade_time_s if fade_time_s > 0.0 else 1.0
    return min(scale + step, target) if target > scale else max(scale - step, target)


def resized(values: np.ndarray, harmonics: int) -> np.ndarray:
    """``values`` for ``harmonics`` harmonics: cut, or padded with zeros."""
    kept = np.zeros(harmonics, dtype=complex)
    count = min(harmonics, values.size)
    kept[:count] = values[:count]
    return kept


class PlayedWaveform:
    """The waveform's and the probe's coefficients (W, complex), and what the heater played of them (module notes).

    Parameters
    ----------
    harmonics : int
    """

    def __init__(self, harmonics: int):
        self.coefficients = np.zeros(harmonics, dtype=complex)
        self.probe = np.zeros(harmonics, dtype=complex)
        self._refresh()
        #: What T2's readings answer: the coefficients the heater played the tick before.
        self.heard = self.played
        #: The fade the heater played the waveform at last tick (0: nothing played).
        self.scale_played = 0.0
        self._effect: tuple | None = None

    def _refresh(self) -> None:
        #: What the heater plays from the next output on: the waveform and the probe.
        self.played = self.coefficients + self.probe
        self._plain = [complex(value) for value in self.played]

    def set(self, coefficients: np.ndarray, probe: np.ndarray) -> None:
        """Play these coefficients and this probe from the next output on."""
        self.coefficients, self.probe = coefficients, probe
        self._refresh()

    def resize(self, harmonics: int) -> None:
        """Keep what is played, as far as it goes, for another number of harmonics (and what the readings answer:
        the effect of what was played last tick is taken at the new number too)."""
        heard = resized(self.heard, harmonics)
        self.set(resized(self.coefficients, harmonics), resized(self.probe, harmonics))
        self.heard = heard

    def clear(self) -> None:
        """Nothing to play (the learning starts again from the model's plant)."""
        self.set(np.zeros_like(self.coefficients), np.zeros_like(self.probe))

    def value(self, rotor: complex) -> float:
        """The power played at the phase whose ``exp(j phase)`` is ``rotor`` (W, before the fade)."""
        return harmonic_sum(self._plain, rotor)

    @property
    def changed(self) -> bool:
        """What the heater plays is not what the readings answer yet."""
        return self.heard is not self.played

    def change_K(self, plant: np.ndarray) -> float:
        """How far the change moves T2, through ``plant`` (K/W per harmonic), harmonics together (K)."""
        return float(np.sum(np.abs(plant * (self.played - self.heard))))

    def energy_kept(self, rotor: complex, advance_rad: float) -> float:
        """The power to add for the tick where the waveform changes, so that the energy it delivers goes on as if
        it had always been the new one (W); ``advance_rad``: the cooler's phase advance over a period.

        Changing ``u`` at tick K moves the constant a held waveform delivers by
        ``T Re sum_n (u_n - u'_n) exp(j n phase_K) / (exp(j n omega T) - 1)``, which depends on where in the
        period the change falls: a kick the flange integrates into T2's mean (a few microkelvin for a change
        of a milliwatt, every learning step, below 0.1 Hz). This gives it back."""
        turn = cmath.exp(1j * advance_rad)
        power, step, kept = 1.0 + 0j, 1.0 + 0j, 0.0
        for new, old in zip(self.played, self.heard):
            power *= rotor
            step *= turn
            kept += ((new - old) * power / (step - 1.0)).real
        return kept

    def heard_now(self) -> None:
        """The readings from the next tick on answer what is played now."""
        self.heard = self.played

    def play(self, rotor: complex, advance_rad: float, plant: np.ndarray, scale: float) -> tuple[float, float]:
        """The power to play this tick at the phase whose ``exp(j phase)`` is ``rotor``, before the fade
        ``scale`` it is played at (W), with the energy a change keeps; and how far the change, if any, moves
        T2 through ``plant`` (K; 0: no change). The readings from the next tick on answer it."""
        value = self.value(rotor)
        self.scale_played = scale
        if not self.changed:
            return value, 0.0
        value += self.energy_kept(rotor, advance_rad)
        change_K = self.change_K(plant)
        self.heard_now()
        return value, change_K

    def effect(self, plant: np.ndarray) -> np.ndarray:
        """What the heater played last tick, through ``plant`` (K/W): its effect on T2 (K per harmonic), cached."""
        scale, heard, cache = self.scale_played, self.heard, self._effect
        if cache is None or cache[0] != scale or cache[1] is not heard or cache[2] is not plant:
            cache = self._effect = (scale, heard, plant, plant * heard * scale)
        return cache[3]


__all__ = ["PlayedWaveform", "faded", "harmonic_sum", "resized"]
