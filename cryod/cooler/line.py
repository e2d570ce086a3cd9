"""The pulse-tube cooler's line as measured in T5: frequency, amplitude, phase, harmonics, drift.

The analysis never takes the cooler's oscillation from the model: records come
from other days and other cryostats, with their own PTC phase, amplitude and
frequency. It measures them in the PTC-stage thermometer (T5), where the line
is 0.1 K against 0.3 mK of noise, and hands them to the simulator. What the
model decides is only the *form*: which harmonic orders exist and whether the
frequency drifts. A model without harmonics is replayed with the fundamental
alone, so harmonics left in T5 show up as a discrepancy; the candidate
``ptc_harmonics`` adds them.

The fit is linear least squares of

    T5(t) - [G3 P](t) = baseline(t) + sum_k (s_k sin(k theta(t)) + c_k cos(k theta(t)))

with ``theta(t) = omega0 (t - t0) + drift phase``, ``t0`` the record's first
instant (the simulator's phase reference), computed by the simulator's own
:class:`cryod.model.cooler_cycle.CoolerCycle`. The baseline columns (offset,
initial-state response) come from the caller. The frequency is found from the
spectrum and refined by :func:`scipy.optimize.minimize_scalar`; a drift by
following the phase in short windows, then :func:`scipy.optimize.least_squares`
on the whole record.

Examples
--------
>>> import numpy as np
>>> t = np.arange(0.0, 600.0, 0.08)
>>> stage = 3.34 + 0.12 * np.sin(10.8 * t + 1.0) + 0.01 * np.sin(2 * 10.8 * t + 0.3)
>>> line = estimate_ptc_line(t, stage, np.ones((t.size, 1)), orders=(1, 2))
>>> round(line.angular_frequency_rad_s, 4), round(line.components[1].amplitude_K, 4)
(10.8, 0.01)
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import interpolate, ndimage, optimize

from cryod.cooler.line_fit import wrap_phase
from cryod.cooler.phase import CoolerPhaseTracker
from cryod.model import CoolerFrequencyDrift, CoolerHarmonic, CryostatModel
from cryod.model.cooler_cycle import CoolerCycle, MeasuredCoolerCycle

#: Search band of the cooler's fundamental (rad/s): 0.3 Hz up to the Nyquist frequency.
LOWEST_LINE_ANGULAR_FREQUENCY = 2.0 * math.pi * 0.3
#: Window of the phase track used to find a frequency drift: at least this many periods ...
PHASE_TRACK_PERIODS = 15
#: ... and at least this fraction of the record.
PHASE_TRACK_FRACTION = 1.0 / 200.0


@dataclass(frozen=True)
class LineComponent:
    """One harmonic order of the line: ``amplitude_K * sin(order * theta + phase_rad)``."""

    order: int
    amplitude_K: float
    phase_rad: float
    amplitude_uncertainty_K: float

    @property
    def significance(self) -> float:
        """Amplitude over its standard error."""
        return self.amplitude_K / self.amplitude_uncertainty_K if self.amplitude_uncertainty_K > 0 else math.inf


@dataclass(frozen=True)
class PtcLine:
    """The cooler's oscillation at its second stage, as measured in one record.

    Attributes
    ----------
    angular_frequency_rad_s : float
        Fundamental angular frequency at the record's start (rad/s).
    components : tuple of LineComponent
        Fundamental first, then harmonics by order; phases referenced to the
        record's first instant.
    drift : CoolerFrequencyDrift or None
        Frequency change over the record, in the model's form.
    frequency_uncertainty_rad_s : float
        Standard error of the fundamental's frequency.
    cycle : MeasuredCoolerCycle or None
        The phase measured sample by sample in T5 (:func:`measured_cycle`),
        when the line is replayed with it; ``drift`` is then the model's form
        fitted to that phase (what an extended model keeps of it).
    """

    angular_frequency_rad_s: float
    components: tuple[LineComponent, ...]
    drift: CoolerFrequencyDrift | None = None
    frequency_uncertainty_rad_s: float = 0.0
    cycle: MeasuredCoolerCycle | None = field(default=None, compare=False)

    @property
    def fundamental(self) -> LineComponent:
        return self.components[0]

    @property
    def orders(self) -> tuple[int, ...]:
        return tuple(c.order for c in self.components)

    def phase_rad(self, elapsed_s) -> np.ndarray:
        """Fundamental phase theta (rad) at ``elapsed_s`` after the record's first instant."""
        return self.ptc_cycle.phase_rad(np.asarray(elapsed_s, dtype=float))

    @property
    def ptc_cycle(self):
        """The cycle the line is replayed with: the measured one, else the model's form."""
        return self.cycle if self.cycle is not None else CoolerCycle(self.angular_frequency_rad_s, self.drift)

    def applied_to(self, model: CryostatModel) -> CryostatModel:
        """``model`` with its PTC source (and drift) replaced by this measured line.

        The heat capacity C of the source, which only scales the model's own
        PTC-to-flange path, is kept. When the model's PTC-stage thermometer
        lags (``sensor_lag.ptc_stage_thermometer_time_constant_s``), the line
        measured in T5 is what that thermometer shows: the source is the line
        before the lag, each order k larger by ``|1 + j k omega tau|`` and
        earlier by ``atan(k omega tau)``.
        """
        lag = model.effects.sensor_lag
        tau = lag.ptc_stage_thermometer_time_constant_s if lag is not None else 0.0
        sources = []
        for c in self.components:
            before_lag = complex(1.0, c.order * self.angular_frequency_rad_s * tau)
            sources.append((c.order, c.amplitude_K * abs(before_lag), wrap_phase(c.phase_rad + cmath.phase(before_lag))))
        harmonics = tuple(CoolerHarmonic(order, amplitude, phase) for order, amplitude, phase in sources[1:])
        changed = model.with_ptc(
            angular_frequency_rad_s=self.angular_frequency_rad_s,
            ptc_stage_amplitude_K=sources[0][1],
            phase_rad=sources[0][2],
            harmonics=harmonics,
        )
        return changed.with_effects(ptc_frequency_drift=self.drift)

    def shape_for(self, model: CryostatModel) -> CryostatModel:
        """``model`` given this line's harmonic content and drift, in the model's own amplitude and phase.

        What an extended model keeps of a measured line: each harmonic's size
        relative to the fundamental and its phase relative to the fundamental's,
        so the waveform is the measured one on the model's own fundamental.
        """
        scale = model.ptc.ptc_stage_amplitude_K / self.fundamental.amplitude_K if self.fundamental.amplitude_K else 0.0
        shift = model.ptc.phase_rad - self.fundamental.phase_rad
        harmonics = tuple(
            CoolerHarmonic(c.order, c.amplitude_K * scale, wrap_phase(c.phase_rad + c.order * shift))
            for c in self.components[1:]
        )
        return model.with_ptc(harmonics=harmonics)


def aliased_angular_frequency(angular_frequency_rad_s: float, sample_interval_s: float) -> float:
    """Where a line appears in a record sampled every ``sample_interval_s`` (rad/s, 0 to Nyquist)."""
    sampling = 2.0 * math.pi / sample_interval_s
    return abs((angular_frequency_rad_s + 0.5 * sampling) % sampling - 0.5 * sampling)


def measurable_orders(angular_frequency_rad_s: float, sample_interval_s: float, most: int = 5,
                      separation_rad_s: float = 0.3) -> tuple[int, ...]:
    """Harmonic orders 1, 2, ... that a record sampled every ``sample_interval_s`` can tell apart.

    Orders above the Nyquist frequency are kept when their alias stays
    ``separation_rad_s`` away from 0, from the Nyquist frequency and from every
    lower order's alias: the fit uses the sample instants, so an aliased
    harmonic is measured as well as any other.
    """
    nyquist = math.pi / sample_interval_s
    kept, seen = [1], [aliased_angular_frequency(angular_frequency_rad_s, sample_interval_s)]
    for order in range(2, most + 1):
        alias = aliased_angular_frequency(order * angular_frequency_rad_s, sample_interval_s)
        if alias < separation_rad_s or nyquist - alias < separation_rad_s:
            continue
        if all(abs(alias - other) >= separation_rad_s for other in seen):
            kept.append(order)
            seen.append(alias)
    return tuple(kept)


def _line_columns(phase: np.ndarray, orders) -> np.ndarray:
    columns = []
    for order in orders:
        columns.append(np.sin(order * phase))
        columns.append(np.cos(order * phase))
    return np.column_stack(columns)


@dataclass(frozen=True)
class _LinearLineFit:
    components: tuple[LineComponent, ...]
    residual: np.ndarray          # on the fitted samples
    sum_of_squares: float


def _fit_components(values: np.ndarray, baseline: np.ndarray, phase: np.ndarray, orders, mask) -> _LinearLineFit:
    """Linear least squares of baseline + line at a given phase, on the samples in ``mask``."""
    design = np.column_stack([baseline[mask], _line_columns(phase[mask], orders)])
    target = values[mask]
    solution, *_ = np.linalg.lstsq(design, target, rcond=None)
    residual = target - design @ solution
    dof = max(target.size - design.shape[1], 1)
    variance = float(residual @ residual) / dof
    base = baseline.shape[1]
    # white-residual standard error of each sine/cosine coefficient, from the normal matrix
    try:
        inverse_diagonal = np.diag(np.linalg.inv(design.T @ design))
    except np.linalg.LinAlgError:
        inverse_diagonal = np.full(design.shape[1], np.nan)
    components = []
    for index, order in enumerate(orders):
        s_coefficient, c_coefficient = solution[base + 2 * index], solution[base + 2 * index + 1]
        error = math.sqrt(max(0.5 * variance * (inverse_diagonal[base + 2 * index]
                                                + inverse_diagonal[base + 2 * index + 1]), 0.0))
        components.append(LineComponent(
            order=int(order),
            amplitude_K=float(math.hypot(s_coefficient, c_coefficient)),
            phase_rad=float(wrap_phase(math.atan2(c_coefficient, s_coefficient))),
            amplitude_uncertainty_K=error,
        ))
    return _LinearLineFit(tuple(components), residual, float(residual @ residual))


def coarse_line_frequency(elapsed_s: np.ndarray, values: np.ndarray) -> float:
    """Angular frequency (rad/s) of the strongest line above 0.3 Hz, from the spectrum.

    The record is put on a uniform grid (sampling jitter is harmless here),
    slow changes are taken out with a 5 s moving average, and the highest bin
    of the Hann-windowed spectrum is refined by parabolic interpolation.
    """
    interval = float(np.median(np.diff(elapsed_s)))
    grid = np.arange(elapsed_s[0], elapsed_s[-1], interval)
    uniform = np.interp(grid, elapsed_s, values)
    window = max(3, int(round(5.0 / interval)))
    high_passed = uniform - ndimage.uniform_filter1d(uniform, window, mode="nearest")
    spectrum = np.abs(np.fft.rfft(high_passed * np.hanning(grid.size)))
    angular = 2.0 * math.pi * np.fft.rfftfreq(grid.size, interval)
    band = np.flatnonzero((angular >= LOWEST_LINE_ANGULAR_FREQUENCY) & (angular < 0.98 * math.pi / interval))
    if band.size < 3:
        raise ValueError("record too short or too coarsely sampled to find the PTC line")
    peak = band[int(np.argmax(spectrum[band]))]
    if 0 < peak < spectrum.size - 1:
        left, centre, right = np.log(spectrum[peak - 1: peak + 2] + 1e-300)
        denominator = left - 2.0 * centre + right
        shift = 0.5 * (left - right) / denominator if denominator < 0 else 0.0
        return float(angular[peak] + np.clip(shift, -0.5, 0.5) * (angular[1] - angular[0]))
    return float(angular[peak])


def estimate_ptc_line(elapsed_s, stage_signal_K, baseline_columns, *, mask=None, orders=(1,),
                      drift: bool = False, angular_frequency_rad_s: float | None = None,
                      significant_only: bool = False, significance_threshold: float = 5.0,
                      cycle: MeasuredCoolerCycle | None = None) -> PtcLine:
    """Measure the line in T5.

    Parameters
    ----------
    elapsed_s : array_like
        Seconds since the record's first instant.
    stage_signal_K : array_like
        T5 less the model's heater-driven part (K).
    baseline_columns : numpy.ndarray
        Regressors fitted alongside (n x m): offset, initial-state response.
    mask : array_like of bool, optional
        Samples used for the fit (default all).
    orders : sequence of int
        Harmonic orders to fit; must include 1.
    drift : bool
        Also fit a frequency drift (rate, and a wander when it is significant).
    angular_frequency_rad_s : float, optional
        Start from this frequency instead of searching the spectrum.
    significant_only : bool
        Keep only harmonics (order > 1) above ``significance_threshold`` standard errors.
    cycle : MeasuredCoolerCycle, optional
        The phase measured in T5 (:func:`measured_cycle`): the components are
        fitted at it, and ``drift`` is the model's form fitted to it
        (:func:`fit_drift_to_phase`).

    Returns
    -------
    PtcLine
    """
    elapsed_s = np.asarray(elapsed_s, dtype=float)
    values = np.asarray(stage_signal_K, dtype=float)
    baseline = np.asarray(baseline_columns, dtype=float).reshape(elapsed_s.size, -1)
    mask = np.ones(elapsed_s.size, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    orders = tuple(sorted(set(int(k) for k in orders) | {1}))
    if cycle is not None:
        fit = _fit_components(values, baseline, cycle.phase_rad(elapsed_s), orders, mask)
        components = fit.components
        if significant_only:
            components = tuple(c for c in components if c.order == 1 or c.significance >= significance_threshold)
        omega, drift_form = fit_drift_to_phase(cycle)
        return PtcLine(omega, components, drift_form, 0.0, cycle)
    duration = float(elapsed_s[-1] - elapsed_s[0])
    if angular_frequency_rad_s is None:
        angular_frequency_rad_s = coarse_line_frequency(elapsed_s, values)
    bin_width = 2.0 * math.pi / duration

    def sum_of_squares(omega: float) -> float:
        return _fit_components(values, baseline, omega * elapsed_s, (1,), mask).sum_of_squares

    refined = optimize.minimize_scalar(
        sum_of_squares, bounds=(angular_frequency_rad_s - 1.5 * bin_width, angular_frequency_rad_s + 1.5 * bin_width),
        method="bounded", options={"xatol": 1e-7})
    omega = float(refined.x)
    fit = _fit_components(values, baseline, omega * elapsed_s, orders, mask)
    frequency_error = _frequency_uncertainty(fit, elapsed_s[mask])
    drift_model = None
    if drift:
        omega, drift_model = _fit_drift(elapsed_s, values, baseline, mask, omega, orders)
        fit = _fit_components(values, baseline, CoolerCycle(omega, drift_model).phase_rad(elapsed_s), orders, mask)
    components = fit.components
    if significant_only:
        components = tuple(c for c in components if c.order == 1 or c.significance >= significance_threshold)
    return PtcLine(omega, components, drift_model, frequency_error)


def _frequency_uncertainty(fit: _LinearLineFit, elapsed_s: np.ndarray) -> float:
    """Standard error of a sinusoid's frequency: sqrt(12) sigma / (A T sqrt(N/2)) (white noise)."""
    amplitude = fit.components[0].amplitude_K
    if amplitude <= 0.0 or elapsed_s.size < 4:
        return math.inf
    sigma = math.sqrt(fit.sum_of_squares / elapsed_s.size)
    span = float(elapsed_s[-1] - elapsed_s[0])
    return float(math.sqrt(12.0) * sigma / (amplitude * span * math.sqrt(elapsed_s.size / 2.0)))


# ---------------------------------------------------------------------------
# frequency drift
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class PhaseTrack:
    """Phase of the fundamental in successive windows, against a fixed frequency.

    Attributes
    ----------
    centre_s : numpy.ndarray
        Window centres (s since the record's start).
    phase_rad : numpy.ndarray
        Unwrapped phase of ``sin(omega0 t + phase)`` in each window.
    uncertainty_rad : numpy.ndarray
        Standard error of each phase.
    angular_frequency_rad_s : float
        The fixed frequency omega0 the phases are measured against.
    """

    centre_s: np.ndarray
    phase_rad: np.ndarray
    uncertainty_rad: np.ndarray
    angular_frequency_rad_s: float


def phase_track(elapsed_s, values, angular_frequency_rad_s: float) -> PhaseTrack:
    """Follow the fundamental's phase in windows of 15 periods (or 1/200 of the record).

    Each window is fitted with an offset, a slope and the line at the fixed
    frequency; the phases are unwrapped in time order.
    """
    elapsed_s = np.asarray(elapsed_s, dtype=float)
    values = np.asarray(values, dtype=float)
    duration = float(elapsed_s[-1] - elapsed_s[0])
    window = max(PHASE_TRACK_PERIODS * 2.0 * math.pi / angular_frequency_rad_s, PHASE_TRACK_FRACTION * duration)
    edges = np.arange(elapsed_s[0], elapsed_s[-1] + 1e-9, window)
    bounds = np.searchsorted(elapsed_s, edges)
    centres, phases, errors = [], [], []
    for start, stop in zip(bounds[:-1], bounds[1:]):
        if stop - start < 12:
            continue
        t = elapsed_s[start:stop]
        baseline = np.column_stack([np.ones(t.size), t - t.mean()])
        fit = _fit_components(values[start:stop], baseline, angular_frequency_rad_s * t, (1,),
                              np.ones(t.size, dtype=bool))
        component = fit.components[0]
        if component.amplitude_K <= 0.0:
            continue
        centres.append(float(t.mean()))
        phases.append(component.phase_rad)
        errors.append(max(component.amplitude_uncertainty_K / component.amplitude_K, 1e-9))
    return PhaseTrack(np.asarray(centres), np.unwrap(np.asarray(phases)), np.asarray(errors),
                      float(angular_frequency_rad_s))


@dataclass(frozen=True)
class DriftTrackFit:
    """Least-squares fit of a phase track by the model's drift form.

    Attributes
    ----------
    frequency_offset_rad_s : float
        Correction to the fixed frequency at the record's start.
    drift : CoolerFrequencyDrift or None
        Rate (and wander, when significant).
    rate_uncertainty_rad_s_per_hour : float
    chi_square_constant : float
        Chi-square of the track against a constant frequency.
    chi_square : float
        Chi-square of the track against the fitted drift.
    """

    frequency_offset_rad_s: float
    drift: CoolerFrequencyDrift | None
    rate_uncertainty_rad_s_per_hour: float
    chi_square_constant: float
    chi_square: float


def fit_phase_track(track: PhaseTrack, duration_s: float) -> DriftTrackFit:
    """Fit offset + frequency offset + rate (quadratic phase), then try a sinusoidal wander.

    The wander of the model's form, ``w sin(2 pi t / P)`` in frequency, is
    kept when it lowers the chi-square by more than 25 and by more than a
    fifth; its period is searched on a grid from a tenth of the record to four
    records.
    """
    t, phase, weight = track.centre_s, track.phase_rad, 1.0 / track.uncertainty_rad
    if t.size < 4:
        return DriftTrackFit(0.0, None, math.inf, 0.0, 0.0)

    def solve(columns):
        design = np.column_stack(columns) * weight[:, None]
        solution, *_ = np.linalg.lstsq(design, phase * weight, rcond=None)
        residual = phase * weight - design @ solution
        return solution, float(residual @ residual), design

    _, chi_constant, _ = solve([np.ones_like(t), t])
    quadratic, chi_quadratic, design = solve([np.ones_like(t), t, t ** 2])
    try:
        covariance = np.linalg.inv(design.T @ design) * max(chi_quadratic / max(t.size - 3, 1), 1.0)
        rate_error = 2.0 * 3600.0 * math.sqrt(covariance[2, 2])
    except np.linalg.LinAlgError:
        rate_error = math.inf
    best = (chi_quadratic, quadratic[1], CoolerFrequencyDrift(rate_rad_s_per_hour=float(2.0 * 3600.0 * quadratic[2])))
    for period in np.geomspace(duration_s / 10.0, 4.0 * duration_s, 40):
        wander_phase = period / (2.0 * math.pi) * (1.0 - np.cos(2.0 * math.pi * t / period))
        solution, chi, _ = solve([np.ones_like(t), t, t ** 2, wander_phase])
        if solution[3] > 0.0 and chi < best[0]:
            best = (chi, solution[1], CoolerFrequencyDrift(float(2.0 * 3600.0 * solution[2]), float(solution[3]),
                                                        float(period)))
    chi, offset, drift = best
    if drift.wander_amplitude_rad_s > 0.0 and not (chi_quadratic - chi > max(25.0, 0.2 * chi_quadratic)):
        chi, offset, drift = chi_quadratic, quadratic[1], CoolerFrequencyDrift(float(2.0 * 3600.0 * quadratic[2]))
    return DriftTrackFit(float(offset), drift, rate_error, chi_constant, chi)


def _fit_drift(elapsed_s, values, baseline, mask, omega, orders):
    """Drift from the phase track, refined on the T5 samples by least squares."""
    duration = float(elapsed_s[-1] - elapsed_s[0])
    track = phase_track(elapsed_s, values, omega)
    start = fit_phase_track(track, duration)
    omega0 = omega + start.frequency_offset_rad_s
    drift = start.drift or CoolerFrequencyDrift()
    with_wander = drift.wander_amplitude_rad_s > 0.0

    def unpack(x):
        x = [float(value) for value in x]
        if with_wander:
            return x[0], CoolerFrequencyDrift(x[1], x[2], x[3])
        return x[0], CoolerFrequencyDrift(x[1])

    def residual(x):
        frequency, model = unpack(x)
        return _fit_components(values, baseline, CoolerCycle(frequency, model).phase_rad(elapsed_s), orders,
                               mask).residual

    x0 = [omega0, drift.rate_rad_s_per_hour]
    lower, upper = [omega0 - 0.5, -np.inf], [omega0 + 0.5, np.inf]
    if with_wander:
        x0 += [drift.wander_amplitude_rad_s, drift.wander_period_s]
        lower += [0.0, drift.wander_period_s / 3.0]
        upper += [np.inf, drift.wander_period_s * 3.0]
    scale = [1e-4, 1e-3] + ([1e-3, 0.1 * drift.wander_period_s] if with_wander else [])
    result = optimize.least_squares(residual, x0, bounds=(lower, upper), x_scale=scale, method="trf",
                                    max_nfev=60)
    frequency, model = unpack(result.x)
    return float(frequency), model


# ---------------------------------------------------------------------------
# the phase measured sample by sample
# ---------------------------------------------------------------------------
#: Knot spacing of the spline that smooths the tracker's phase (s): well above the tracker's response time.
TRACKED_PHASE_KNOTS_S = 15.0
#: Windows in which the smoothed phase is corrected against T5 itself (s).
PHASE_CORRECTION_WINDOW_S = 30.0
#: Harmonic orders fitted in those windows (so that T5's harmonics do not bias the fundamental's phase).
PHASE_CORRECTION_ORDERS = (1, 2, 3)


def measured_cycle(elapsed_s, stage_signal_K, nominal_rad_s: float) -> MeasuredCoolerCycle:
    """The cooler's phase followed sample by sample in T5: the feedforward's tracker, made zero-lag.

    1. :class:`cryod.cooler.phase.CoolerPhaseTracker` (the same
       phase-locked loop the feedforward locks to) runs over the record.
    2. Its phase, less a straight line, is smoothed by a least-squares cubic
       spline with knots every :data:`TRACKED_PHASE_KNOTS_S` (the loop's
       jitter, about 1 mrad, averages out; before lock the spline is
       extrapolated).
    3. A loop of the second type lags a changing frequency by
       (d omega / dt) / omega_n^2 (1 mrad for a 1 % wander over ten minutes):
       in windows of :data:`PHASE_CORRECTION_WINDOW_S` the phase of T5's
       fundamental against the smoothed phase (offset, slope and the harmonics
       fitted alongside) is measured, and its smooth interpolation added.

    The phase is referenced to 0 at the first instant; the frequency is its
    derivative. On a line of 0.12 K against 0.3 mK of noise, what is left
    adds less than 1 % to T5's residual variance (a wander of +-1 % with a
    ten-minute period included).

    Parameters
    ----------
    elapsed_s : array_like
        Instants (s since the record's first), increasing.
    stage_signal_K : array_like
        T5 (less the model's heater part), K; NaN where missing.
    nominal_rad_s : float
        Where the tracker starts (rad/s).

    Returns
    -------
    MeasuredCoolerCycle

    Examples
    --------
    >>> t = np.arange(0.0, 600.0, 0.08)
    >>> phase = 10.8 * t + 3.0 * np.sin(2 * np.pi * t / 300.0)
    >>> cycle = measured_cycle(t, 3.3 + 0.12 * np.sin(phase + 1.0), 10.83)
    >>> error = cycle.phase_rad(t) - (phase - phase[0])
    >>> bool(np.ptp(error[t > 10.0]) < 2e-3)
    True
    """
    elapsed_s = np.asarray(elapsed_s, dtype=float)
    values = np.asarray(stage_signal_K, dtype=float)
    present = np.isfinite(values)
    t, values = elapsed_s[present], values[present]
    tracker = CoolerPhaseTracker(nominal_rad_s)
    states = [tracker.update(time_s, value) for time_s, value in zip(t.tolist(), values.tolist())]
    phase = np.array([state.phase_rad for state in states])
    locked = np.array([state.locked for state in states])
    first = int(np.argmax(locked)) if locked.any() else 0
    span = t[-1] - t[first]
    if span <= 2.0 * TRACKED_PHASE_KNOTS_S:
        raise ValueError("the cooler's line could not be followed in T5: the tracker did not lock "
                         f"({t.size} readings over {t[-1] - t[0]:.1f} s)")
    slope = (phase[-1] - phase[first]) / span
    ramp = phase[first] + slope * (t - t[first])
    knots = np.arange(t[first] + TRACKED_PHASE_KNOTS_S, t[-1] - 0.5 * TRACKED_PHASE_KNOTS_S, TRACKED_PHASE_KNOTS_S)
    order = 3
    knot_vector = np.r_[[t[first]] * (order + 1), knots, [t[-1]] * (order + 1)]
    spline = interpolate.make_lsq_spline(t[first:], (phase - ramp)[first:], knot_vector, k=order)
    smoothed = ramp + spline(t, extrapolate=True)
    smoothed_frequency = slope + spline.derivative()(t, extrapolate=True)
    centres: list[float] = []
    corrections: list[float] = []
    for start in np.arange(t[0], t[-1], PHASE_CORRECTION_WINDOW_S):
        window = (t >= start) & (t < start + PHASE_CORRECTION_WINDOW_S)
        if np.count_nonzero(window) < 40:
            continue
        local_t, local_phase = t[window], smoothed[window]
        columns = [np.ones(local_t.size), local_t - local_t.mean()]
        for harmonic in PHASE_CORRECTION_ORDERS:
            columns += [np.cos(harmonic * local_phase), np.sin(harmonic * local_phase)]
        solution, *_ = np.linalg.lstsq(np.column_stack(columns), values[window], rcond=None)
        centres.append(float(local_t.mean()))
        corrections.append(math.atan2(-solution[3], solution[2]))     # A cos(phase + d) = A cos d cos - A sin d sin
    unwrapped = np.unwrap(np.asarray(corrections))
    if len(centres) >= 4:
        correction = interpolate.CubicSpline(centres, unwrapped - unwrapped.mean(), extrapolate=True)
        smoothed = smoothed + correction(t)
        smoothed_frequency = smoothed_frequency + correction.derivative()(t)
    start_phase, start_frequency = smoothed[0], smoothed_frequency[0]
    if t[0] > 0.0:                       # the first readings were missing: the reference is still the record's start
        start_phase -= start_frequency * t[0]
    return MeasuredCoolerCycle(t, smoothed - start_phase, smoothed_frequency)


#: A sinusoidal wander is kept in the drift form when its amplitude is above this many standard errors.
WANDER_SIGNIFICANCE = 5.0
#: The phase measured is correlated over about this long (s): its samples count as independent once per this.
PHASE_CORRELATION_S = 15.0


def fit_drift_to_phase(cycle: MeasuredCoolerCycle) -> tuple[float, CoolerFrequencyDrift]:
    """The model's drift form fitted to a measured phase: (omega_0, drift).

    ``theta(t) = theta_0 + omega_0 t + r t^2 / 7200 + (w P / 2 pi)(cos psi - cos(2 pi t / P + psi))``:
    linear least squares for every wander period P on a grid (a tenth of the
    record to four records), refined by bounded Brent; the wander is kept when
    its amplitude w is above :data:`WANDER_SIGNIFICANCE` standard errors, else
    the rate alone. Samples are taken once per second.
    """
    t = cycle.elapsed_s
    step = max(1, int(round(1.0 / max(float(np.median(np.diff(t))), 1e-6))))
    t = t[::step]
    phase = cycle.phase_values_rad[::step]
    duration = float(t[-1] - t[0])
    centred = t / 3600.0

    def solve(period):
        columns = [np.ones(t.size), t, 0.5 * 3600.0 * centred ** 2]
        if period is not None:
            angle = 2.0 * math.pi * t / period
            columns += [np.cos(angle), np.sin(angle)]
        design = np.column_stack(columns)
        solution, *_ = np.linalg.lstsq(design, phase, rcond=None)
        residual = phase - design @ solution
        return solution, float(residual @ residual), design

    quadratic, quadratic_chi, design = solve(None)
    periods = np.geomspace(duration / 10.0, 4.0 * duration, 40)
    chis = [solve(period)[1] for period in periods]
    best = int(np.argmin(chis))
    low = periods[max(best - 1, 0)]
    high = periods[min(best + 1, periods.size - 1)]
    refined = optimize.minimize_scalar(lambda period: solve(period)[1], bounds=(low, high), method="bounded",
                                       options={"xatol": 1e-3 * periods[best]})
    period = float(refined.x) if refined.fun <= chis[best] else float(periods[best])
    solution, chi, design = solve(period)
    independent = max(duration / PHASE_CORRELATION_S, 6.0)
    variance = chi / max(independent - design.shape[1], 1.0)
    scale = 2.0 * math.pi / period
    cos_part, sin_part = solution[3], solution[4]
    # (w P / 2 pi)(cos psi - cos(a + psi)) = const - (w/scale) cos psi cos a + (w/scale) sin psi sin a
    amplitude = math.hypot(cos_part, sin_part) * scale
    try:
        covariance = np.linalg.inv(design.T @ design) * variance * (t.size / independent)
        amplitude_error = math.sqrt(max(0.5 * (covariance[3, 3] + covariance[4, 4]), 0.0)) * scale
    except np.linalg.LinAlgError:
        amplitude_error = math.inf
    if amplitude > WANDER_SIGNIFICANCE * amplitude_error and amplitude > 0.0:
        wander_phase = math.atan2(sin_part, -cos_part)
        return float(solution[1]), CoolerFrequencyDrift(float(solution[2]), float(amplitude), period,
                                                     float(wrap_phase(wander_phase)))
    return float(quadratic[1]), CoolerFrequencyDrift(float(quadratic[2]))
