"""The pulse-tube cooler's phase and frequency, tracked sample by sample from T5.

The cooler's second stage (T5) carries its oscillation, about 0.12 K at
10.8 rad/s, hundreds of times the thermometer's noise. A phase-locked loop
follows it: each reading, taken at its own instant, updates a recursive
demodulator of T5 (offset and complex amplitude of each harmonic, relative to
the tracked phase), and the angle of the fundamental's amplitude is the phase
error that steers the tracked phase and frequency (a second-order loop, so a
frequency that wanders is followed without a lasting phase error).

The phase is defined so that T5's fundamental is ``amplitude * cos(phase)``;
everything locked to the cooler (the feedforward's waveform, the analysis'
replay of the line) is a function of this phase.

Readings may come at any instants (an autozero moves some of them by 20 ms):
the demodulator evaluates the phase at each reading's own instant. Lock is
declared when the amplitude is well above ``minimum_amplitude_K`` and the
phase error has stayed small; a vanishing oscillation (cooler stopped, T5
sensor fault) drops the lock, and the tracker then holds its frequency and
waits. A phase jump (a cooler restart) is pulled in within a few seconds.

Examples
--------
>>> import numpy as np
>>> tracker = CoolerPhaseTracker(nominal_rad_s=10.83)
>>> t = np.arange(0.0, 20.0, 0.08)
>>> for time_s, value in zip(t, 3.34 + 0.12 * np.cos(10.9 * t + 0.3)):
...     state = tracker.update(time_s, value)
>>> state.locked, round(state.frequency_rad_s, 2), round(state.amplitude_K, 3)
(True, 10.9, 0.12)
>>> round(float(np.angle(np.exp(1j * (state.phase_rad - (10.9 * t[-1] + 0.3))))), 2)   # phase error
0.0
"""

from __future__ import annotations

import cmath
import math
from typing import NamedTuple

import numpy as np


class CoolerPhase(NamedTuple):
    """The tracker's state at one reading.

    Attributes
    ----------
    time_s : float
        The reading's instant (s).
    phase_rad : float
        The cooler's phase at that instant (T5's fundamental is ``amplitude * cos(phase)``), unwrapped.
    frequency_rad_s : float
        Angular frequency (rad/s).
    amplitude_K : float
        Amplitude of T5's fundamental (K).
    phase_error_rad : float
        The loop's phase error at this reading (rad).
    locked : bool
        Amplitude and phase error have been within their bounds for ``lock_time_s``.
    """

    time_s: float
    phase_rad: float
    frequency_rad_s: float
    amplitude_K: float
    phase_error_rad: float
    locked: bool

    def phase_at(self, time_s: float) -> float:
        """The phase predicted at another instant (rad), at the present frequency."""
        return self.phase_rad + self.frequency_rad_s * (time_s - self.time_s)


class CoolerPhaseTracker:
    """A phase-locked loop on T5.

    Parameters
    ----------
    nominal_rad_s : float
        Expected angular frequency (the model's), where the loop starts.
    harmonics : int
        Harmonics of T5 demodulated (the fundamental is the phase detector;
        the others keep T5's harmonics from biasing it).
    demodulator_time_s : float
        Time constant of the recursive demodulator (s).
    loop_bandwidth_rad_s : float
        Natural frequency of the phase-locked loop once locked (rad/s); while
        acquiring, four times this.
    damping : float
        Damping of the phase-locked loop.
    minimum_amplitude_K : float
        Below this the oscillation counts as gone (cooler stopped, sensor fault).
    lock_time_s : float
        How long amplitude and phase error must stay within bounds for lock.
    frequency_range : float
        The frequency is held within this fraction of ``nominal_rad_s``.
    """

    #: Phase error (rad) below which the loop counts as settled, and above which it counts as lost.
    SETTLED_ERROR_RAD = 0.05
    LOST_ERROR_RAD = 0.6

    def __init__(self, nominal_rad_s: float, *, harmonics: int = 3, demodulator_time_s: float = 0.5,
                 loop_bandwidth_rad_s: float = 1.0, damping: float = 0.8, minimum_amplitude_K: float = 0.01,
                 lock_time_s: float = 2.0, frequency_range: float = 0.05):
        if not nominal_rad_s > 0.0:
            raise ValueError(f"nominal_rad_s must be > 0, got {nominal_rad_s}")
        if harmonics < 1:
            raise ValueError(f"harmonics must be at least 1, got {harmonics}")
        self.nominal_rad_s = float(nominal_rad_s)
        self.harmonics = int(harmonics)
        self.demodulator_time_s = float(demodulator_time_s)
        self.loop_bandwidth_rad_s = float(loop_bandwidth_rad_s)
        self.damping = float(damping)
        self.minimum_amplitude_K = float(minimum_amplitude_K)
        self.lock_time_s = float(lock_time_s)
        self.frequency_limits = (nominal_rad_s * (1.0 - frequency_range), nominal_rad_s * (1.0 + frequency_range))
        self.reset()

    def reset(self) -> None:
        """Forget everything: start acquiring again at the nominal frequency."""
        self.time_s: float | None = None
        self.phase_rad = 0.0
        self.frequency_rad_s = self.nominal_rad_s
        self.offset_K: float | None = None
        self.amplitudes = [0j] * self.harmonics       # T5 = offset + Re(sum a_n e^{j n phase}); plain complex: fast
        self.error_rad = 0.0
        self._settled_s = 0.0
        self._error_average = math.pi
        self.locked = False
        self.state: CoolerPhase | None = None

    @property
    def amplitude_K(self) -> float:
        return abs(self.amplitudes[0])

    def update(self, time_s: float, ptc_stage_K: float) -> CoolerPhase:
        """Take one T5 reading at its instant; returns the tracker's state at that instant."""
        if self.time_s is None:
            self.time_s = float(time_s)
        dt = float(time_s) - self.time_s
        if dt < 0.0:
            raise ValueError(f"readings out of order: {time_s} s after {self.time_s} s")
        self.time_s = float(time_s)
        phase = self.phase_rad + self.frequency_rad_s * dt
        if math.isfinite(ptc_stage_K):
            phase = self._demodulate_and_steer(phase, float(ptc_stage_K), dt)
        self.phase_rad = phase
        self.state = CoolerPhase(self.time_s, phase, self.frequency_rad_s, self.amplitude_K, self.error_rad,
                                 self.locked)
        return self.state

    def _demodulate_and_steer(self, phase: float, value: float, dt: float) -> float:
        rotor = cmath.exp(1j * phase)
        rotors = [rotor]
        for _ in range(1, self.harmonics):
            rotors.append(rotors[-1] * rotor)
        amplitudes = self.amplitudes
        offset_K = value if self.offset_K is None else self.offset_K    # from the first reading that is a number
        residual = value - offset_K - sum((a * r).real for a, r in zip(amplitudes, rotors))
        gain = min(dt / self.demodulator_time_s, 0.5)
        self.offset_K = offset_K + gain * residual
        step = 2.0 * gain * residual
        amplitudes = [a + step * r.conjugate() for a, r in zip(amplitudes, rotors)]
        present = abs(amplitudes[0]) >= self.minimum_amplitude_K
        if present:
            self.error_rad = cmath.phase(amplitudes[0])
            bandwidth = self.loop_bandwidth_rad_s * (1.0 if self.locked else 4.0)
            correction = min(2.0 * self.damping * bandwidth * dt, 1.0) * self.error_rad
            self.frequency_rad_s = min(max(self.frequency_rad_s + bandwidth ** 2 * dt * self.error_rad,
                                           self.frequency_limits[0]), self.frequency_limits[1])
            phase += correction
            turn = cmath.exp(-1j * correction)          # the reference moved: so do the amplitudes
            turns = turn
            for index in range(self.harmonics):
                amplitudes[index] *= turns
                turns *= turn
        self.amplitudes = amplitudes
        self._judge_lock(present, dt)
        return phase

    def _judge_lock(self, present: bool, dt: float) -> None:
        weight = min(dt / self.lock_time_s, 1.0)
        self._error_average += weight * ((abs(self.error_rad) if present else math.pi) - self._error_average)
        if not present or self._error_average > self.LOST_ERROR_RAD:
            self.locked = False
            self._settled_s = 0.0
            return
        self._settled_s = self._settled_s + dt if abs(self.error_rad) < self.SETTLED_ERROR_RAD else 0.0
        if self._settled_s >= self.lock_time_s:
            self.locked = True


def track_cooler_phase(time_s, ptc_stage_K, nominal_rad_s: float, **options) -> dict:
    """Run the tracker over a whole record (the analysis' view of the cooler).

    Parameters
    ----------
    time_s, ptc_stage_K : array_like
        T5 readings and their instants (s).
    nominal_rad_s : float
        Expected angular frequency (rad/s).
    **options
        Passed to :class:`CoolerPhaseTracker`.

    Returns
    -------
    dict of numpy.ndarray
        ``phase_rad``, ``frequency_rad_s``, ``amplitude_K``, ``locked`` at every reading.
    """
    tracker = CoolerPhaseTracker(nominal_rad_s, **options)
    states = [tracker.update(t, value) for t, value in zip(np.asarray(time_s, float), np.asarray(ptc_stage_K, float))]
    return {"phase_rad": np.array([s.phase_rad for s in states]),
            "frequency_rad_s": np.array([s.frequency_rad_s for s in states]),
            "amplitude_K": np.array([s.amplitude_K for s in states]),
            "locked": np.array([s.locked for s in states])}


def cooler_frequency_rad_s(time_s, ptc_stage_K, nominal_rad_s: float, **options) -> float:
    """The cooler's angular frequency over a stretch of T5 (rad/s), as the daemon follows it.

    The tracker the feedforward locks with (:class:`CoolerPhaseTracker`) runs over the readings;
    the frequency is the slope of the phase it tracked over the readings where it was locked (a
    straight line fitted to the unwrapped phase: the mean frequency, to a few 1e-5 rad/s over
    minutes). Every tool that names the cooler's frequency in a record uses this one estimate.

    Parameters
    ----------
    time_s, ptc_stage_K : array_like
        T5 readings and their instants (s).
    nominal_rad_s : float
        Expected angular frequency (rad/s), where the tracker starts.
    **options
        Passed to :class:`CoolerPhaseTracker`.

    Returns
    -------
    float
        The frequency, or NaN when the tracker never locked (no cooler line on T5).

    Examples
    --------
    >>> t = np.arange(0.0, 120.0, 0.08)
    >>> round(cooler_frequency_rad_s(t, 3.4 + 0.12 * np.sin(10.9 * t + 0.2), 10.83), 4)
    10.9
    """
    time_s = np.asarray(time_s, dtype=float)
    track = track_cooler_phase(time_s, ptc_stage_K, nominal_rad_s, **options)
    locked = track["locked"]
    if locked.sum() < 2:
        return math.nan
    times = time_s[locked]
    return float(np.polyfit(times - times.mean(), track["phase_rad"][locked], 1)[0])
