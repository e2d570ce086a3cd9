"""The pulse-tube cooler's cycle: its phase and angular frequency at any instant.

The one place they are computed: the simulated cryostat drives its PTC paths
with them (:mod:`cryod.model.cooler_path`), and the analysis fits the line it
measures in T5 at them (:mod:`cryod.cooler.line`). With ``t`` the time
since the phase reference (the start of the simulation or of the record)::

    omega(t) = omega_0 + drift offset(t)
    theta(t) = integral of omega from 0 to t = omega_0 t + drift phase(t)

The drift's form is :class:`~cryod.model.parameters.CoolerFrequencyDrift`. A
cycle measured in a record (:class:`MeasuredCoolerCycle`: the phase the analysis
tracks in T5, sample by sample) drives the same paths when a record is
replayed with the cooler's own wander instead of a form.

Examples
--------
>>> from cryod.model.parameters import CoolerFrequencyDrift
>>> cycle = CoolerCycle(10.83, CoolerFrequencyDrift(rate_rad_s_per_hour=0.036))
>>> phase, frequency = cycle.phase_and_frequency(3600.0)
>>> round(float(phase), 1), round(float(frequency), 3)          # rad, rad/s an hour in
(39052.8, 10.866)
>>> CoolerCycle(10.83).phase_rad(np.array([0.0, 0.5]))
array([0.   , 5.415])
"""

from __future__ import annotations

import cmath
from dataclasses import dataclass

import numpy as np

from cryod.model.parameters import CoolerFrequencyDrift


@dataclass(frozen=True)
class CoolerCycle:
    """Phase and angular frequency of the cooler's fundamental over time.

    Parameters
    ----------
    angular_frequency_rad_s : float
        omega_0, the angular frequency at the phase reference (rad/s).
    drift : CoolerFrequencyDrift, optional
        How the frequency changes from there; ``None`` for a constant one.
    """

    angular_frequency_rad_s: float
    drift: CoolerFrequencyDrift | None = None

    def phase_and_frequency(self, elapsed_s):
        """Phase theta (rad, without any component's own phase) and angular frequency omega (rad/s).

        Parameters
        ----------
        elapsed_s : float or numpy.ndarray
            Time since the phase reference (s).

        Returns
        -------
        phase : float or numpy.ndarray
            theta at each instant.
        frequency : float or numpy.ndarray
            omega at each instant; one float when the frequency does not drift.
        """
        omega_0 = self.angular_frequency_rad_s
        if self.drift is None:
            return omega_0 * elapsed_s, omega_0
        return (omega_0 * elapsed_s + self.drift.phase_offset(elapsed_s),
                omega_0 + self.drift.angular_frequency_offset(elapsed_s))

    def phase_rad(self, elapsed_s):
        """Phase theta (rad) at ``elapsed_s`` (s, a float or a numpy array)."""
        return self.phase_and_frequency(elapsed_s)[0]

    def rotor(self, elapsed_s: float) -> tuple[complex, float]:
        """``exp(j theta)`` and omega (rad/s) at one instant: the stepping simulation's fast path."""
        if self.drift is None:
            return cmath.exp(1j * (self.angular_frequency_rad_s * elapsed_s)), self.angular_frequency_rad_s
        phase, frequency = self.phase_and_frequency(elapsed_s)
        return cmath.exp(1j * float(phase)), float(frequency)


class MeasuredCoolerCycle:
    """The cooler's phase and frequency as measured in a record, between its instants.

    Linear interpolation of the phase and the frequency given at increasing
    instants; before the first and after the last, the phase continues at the
    frequency there.

    Parameters
    ----------
    elapsed_s : array_like
        Increasing instants (s since the phase reference).
    phase_rad : array_like
        theta at each instant (rad, unwrapped; 0 at the reference).
    frequency_rad_s : array_like
        omega at each instant (rad/s).

    Examples
    --------
    >>> cycle = MeasuredCoolerCycle([0.0, 1.0, 2.0], [0.0, 10.0, 20.5], [10.0, 10.25, 10.5])
    >>> phase, frequency = cycle.phase_and_frequency(np.array([0.5, 3.0]))
    >>> phase.tolist(), frequency.tolist()
    ([5.0, 31.0], [10.125, 10.5])
    """

    def __init__(self, elapsed_s, phase_rad, frequency_rad_s):
        self.elapsed_s = np.asarray(elapsed_s, dtype=float)
        self.phase_values_rad = np.asarray(phase_rad, dtype=float)
        self.frequency_values_rad_s = np.asarray(frequency_rad_s, dtype=float)
        if not (self.elapsed_s.ndim == 1 and self.elapsed_s.size >= 2
                and self.elapsed_s.shape == self.phase_values_rad.shape == self.frequency_values_rad_s.shape):
            raise ValueError("a measured cycle needs at least two instants, each with a phase and a frequency")
        if np.any(np.diff(self.elapsed_s) <= 0.0):
            raise ValueError("the instants of a measured cycle must increase")

    @property
    def angular_frequency_rad_s(self) -> float:
        """omega at the phase reference (rad/s)."""
        return float(np.interp(0.0, self.elapsed_s, self.frequency_values_rad_s))

    def phase_and_frequency(self, elapsed_s):
        """Phase theta (rad) and angular frequency omega (rad/s) at ``elapsed_s`` (float or array)."""
        times = np.asarray(elapsed_s, dtype=float)
        phase = np.interp(times, self.elapsed_s, self.phase_values_rad)
        frequency = np.interp(times, self.elapsed_s, self.frequency_values_rad_s)
        before, after = times < self.elapsed_s[0], times > self.elapsed_s[-1]
        if np.any(before) or np.any(after):
            phase = np.where(before, self.phase_values_rad[0]
                             + self.frequency_values_rad_s[0] * (times - self.elapsed_s[0]), phase)
            phase = np.where(after, self.phase_values_rad[-1]
                             + self.frequency_values_rad_s[-1] * (times - self.elapsed_s[-1]), phase)
        if np.ndim(phase) == 0:
            return float(phase), float(frequency)
        return phase, frequency

    def phase_rad(self, elapsed_s):
        """Phase theta (rad) at ``elapsed_s`` (s, a float or a numpy array)."""
        return self.phase_and_frequency(elapsed_s)[0]

    def rotor(self, elapsed_s: float) -> tuple[complex, float]:
        """``exp(j theta)`` and omega (rad/s) at one instant."""
        phase, frequency = self.phase_and_frequency(float(elapsed_s))
        return cmath.exp(1j * phase), frequency
