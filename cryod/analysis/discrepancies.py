"""What the simulation gets wrong, quantity by quantity, each with its significance against the noise.

Each :class:`Discrepancy` compares one quantity computed the same way on the
model's prediction and on the measurement, and says by how many standard
errors they differ (standard errors from the *measured* noise):

* residual rms per segment (T2, T5): the model says "noise only", so the
  expected rms is the measured noise; significance ``(sum r^2/s^2 - n)/sqrt(2 n)``;
* the PTC line per segment: T2's amplitude and its lag behind T5;
* harmonics of the line in T5 and T2 (the whole record);
* the line frequency's drift over the record (T5's phase track, less the model's heater-driven part:
  a heater waveform locked to the cooler, the feedforward's, moves T5's phase at the line as it is
  learned, which would read as a drift);
* heater steps: T2's change per watt over the hold, time to 10 % and to 63 %
  of the change (line averaged out over one period);
* heater modulation away from the line: T2's response (K/W) and phase;
* whiteness of the T2 residual (Ljung-Box, lags 1-20 samples) and its
  cross-correlation with the heater (lags 0-1024 samples, log-spaced);
* the measured noise against the model's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from cryod.analysis.record_data import RecordData
from cryod.analysis.replay import Replay
from cryod.analysis.segments import RecordSegment, find_segments, find_steps
from cryod.cooler.line import fit_phase_track, measurable_orders, phase_track
from cryod.cooler.line_fit import fit_line, wrap_phase
from cryod.model import CryostatModel
from cryod.model.dynamics import simulate

#: Lags of the residual's autocorrelation (samples) and of its cross-correlation with the heater.
WHITENESS_LAGS = tuple(range(1, 21))
CROSS_CORRELATION_LAGS = (0, 1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024)
#: Line fits need at least this many periods in a segment.
LINE_PERIODS = 20


@dataclass(frozen=True)
class Discrepancy:
    """One quantity: the model's value, the measured one, and their difference in standard errors."""

    quantity: str
    model: float
    measured: float
    significance: float

    def as_dict(self) -> dict:
        return {"quantity": self.quantity, "model": _finite(self.model), "measured": _finite(self.measured),
                "significance": _finite(self.significance)}


def _finite(value: float):
    value = float(value)
    return value if math.isfinite(value) else None


def _ratio(difference: float, uncertainty: float) -> float:
    if uncertainty > 0.0 and math.isfinite(uncertainty):
        return abs(difference) / uncertainty
    return 0.0 if difference == 0.0 else math.inf


def residual_discrepancies(data: RecordData, replay: Replay, noise_rms_K, segments) -> list[Discrepancy]:
    """Rms of the T2 and T5 residuals in each segment against the measured noise."""
    found = []
    for segment in segments:
        window = slice(segment.start_index, segment.stop_index)
        for name, residual, noise in (("T2", replay.flange_residual_K, noise_rms_K[0]),
                                      ("T5", replay.ptc_stage_residual_K, noise_rms_K[1])):
            values = residual[window]
            values = values[np.isfinite(values)]
            if values.size < 10:
                continue
            count = values.size
            chi_square = float(values @ values) / noise ** 2
            found.append(Discrepancy(f"{name} residual rms (K), {segment.label()}", noise,
                                     math.sqrt(chi_square / count) * noise,
                                     max((chi_square - count) / math.sqrt(2.0 * count), 0.0)))
    return found


def line_discrepancies(data: RecordData, replay: Replay, angular_frequency: float, segments) -> list[Discrepancy]:
    """T2's line amplitude and lag behind T5, per segment long enough for a line fit."""
    found = []
    elapsed = data.elapsed_s
    for segment in segments:
        if segment.duration_s < LINE_PERIODS * 2.0 * math.pi / angular_frequency:
            continue
        window = np.arange(segment.start_index, segment.stop_index)
        window = window[data.valid[window]]
        if window.size < 50:
            continue
        t = elapsed[window]
        measured = fit_line(t, data.flange_K[window], angular_frequency, trend_order=3)
        modelled = fit_line(t, replay.flange_K[window], angular_frequency, trend_order=3)
        stage = fit_line(t, data.ptc_stage_K[window], angular_frequency, trend_order=3)
        error = measured.amplitude_uncertainty[0]
        found.append(Discrepancy(f"T2 line amplitude (K), {segment.label()}", modelled.amplitude[0],
                                 measured.amplitude[0], _ratio(measured.amplitude[0] - modelled.amplitude[0], error)))
        lag_model = wrap_phase(stage.phase_rad[0] - modelled.phase_rad[0])
        lag_measured = wrap_phase(stage.phase_rad[0] - measured.phase_rad[0])
        phase_error = math.hypot(error / max(measured.amplitude[0], 1e-300),
                                 stage.amplitude_uncertainty[0] / max(stage.amplitude[0], 1e-300))
        found.append(Discrepancy(f"T2 line lag behind T5 (rad), {segment.label()}", lag_model, lag_measured,
                                 _ratio(wrap_phase(lag_measured - lag_model), phase_error)))
    return found


def harmonic_discrepancies(data: RecordData, replay: Replay, angular_frequency: float) -> list[Discrepancy]:
    """Amplitude of each harmonic of the line in T5 and T2 over the whole record."""
    valid = data.valid
    t = data.elapsed_s[valid]
    orders = measurable_orders(angular_frequency, data.sample_interval_s)
    if len(orders) < 2:
        return []
    found = []
    for name, measured_values, modelled_values in (("T5", data.ptc_stage_K, replay.ptc_stage_K),
                                                   ("T2", data.flange_K, replay.flange_K)):
        # the model's own prediction is removed first, so the slow parts do not leak into the fit
        residual = measured_values[valid] - modelled_values[valid]
        measured_fit = fit_line(t, measured_values[valid], angular_frequency, orders, trend_order=1)
        modelled_fit = fit_line(t, modelled_values[valid], angular_frequency, orders, trend_order=1)
        residual_fit = fit_line(t, residual, angular_frequency, orders, trend_order=1)
        for index, order in enumerate(orders[1:], start=1):
            found.append(Discrepancy(
                f"{name} harmonic {order} amplitude (K)", modelled_fit.amplitude[index],
                measured_fit.amplitude[index],
                _ratio(residual_fit.amplitude[index], residual_fit.amplitude_uncertainty[index])))
    return found


def drift_discrepancy(data: RecordData, model: CryostatModel, angular_frequency: float) -> list[Discrepancy]:
    """Rate of change of the line frequency over the record (T5 phase track) against the model's.

    The phase is tracked in T5 less the model's heater-driven part (as the line itself is measured,
    :meth:`cryod.analysis.replay.Replayer.stage_line`): the feedforward's waveform reaches T5 through the
    heater's path at the cooler's harmonics, a fraction of a millikelvin against a line of about 0.1 K, and as
    it fades in and is learned it turns T5's phase at the line by a milliradian or two, the curvature of a drift
    of a few microradians per second per hour that the readings' noise would call significant.
    """
    valid = data.valid
    quiet = model.with_ptc(ptc_stage_amplitude_K=0.0, harmonics=()).with_effects(ptc_frequency_drift=None)
    heater_part = simulate(quiet, data.time_s, data.heater_w, heater_change_s=data.heater_change_s).ptc_stage_K
    track = phase_track(data.elapsed_s[valid], (data.ptc_stage_K - heater_part)[valid], angular_frequency)
    fit = fit_phase_track(track, data.duration_s)
    drift = fit.drift
    measured = drift.rate_rad_s_per_hour if drift is not None else 0.0
    modelled = model.effects.ptc_frequency_drift.rate_rad_s_per_hour if model.effects.ptc_frequency_drift else 0.0
    found = [Discrepancy("PTC line frequency drift rate (rad/s per hour)", modelled, measured,
                         _ratio(measured - modelled, fit.rate_uncertainty_rad_s_per_hour))]
    dof = max(track.centre_s.size - 2, 1)
    found.append(Discrepancy("PTC line phase against a fixed frequency: chi-square per degree of freedom",
                             1.0, fit.chi_square_constant / dof,
                             max((fit.chi_square_constant - dof) / math.sqrt(2.0 * dof), 0.0)))
    return found


def _smoothed(values: np.ndarray, samples: int) -> np.ndarray:
    return ndimage.uniform_filter1d(values, max(samples, 1), mode="nearest")


def step_discrepancies(data: RecordData, replay: Replay, noise_rms_K: float, angular_frequency: float,
                       segments) -> list[Discrepancy]:
    """Change per W over the hold, time to 10 % and to 63 % of the change, for each heater step."""
    found = []
    period_samples = int(round(2.0 * math.pi / angular_frequency / data.sample_interval_s))
    measured_all = _smoothed(np.where(data.valid, data.flange_K, replay.flange_K), period_samples)
    modelled_all = _smoothed(replay.flange_K, period_samples)
    smoothed_noise = noise_rms_K / math.sqrt(max(period_samples, 1))
    for step in find_steps(data.time_s, data.heater_w, segments):
        before = slice(max(step.before.start_index, step.before.stop_index - max(period_samples * 10, 50)),
                       step.before.stop_index)
        after = slice(step.after.start_index, step.after.stop_index)
        if step.after.stop_index - step.after.start_index < 4 * max(period_samples, 10):
            continue
        delta_power = step.after_w - step.before_w
        elapsed = data.time_s[after] - step.time_s
        tail = max(len(elapsed) // 10, period_samples)
        results = {}
        for name, series in (("model", modelled_all), ("measured", measured_all)):
            start_level = float(np.mean(series[before]))
            change = float(np.mean(series[after][-tail:])) - start_level
            fraction = (series[after] - start_level) / change if change else np.zeros(len(elapsed))
            results[name] = (change / delta_power, _crossing(elapsed, fraction, 0.1), _crossing(elapsed, fraction, 0.63),
                             change)
        label = f"step {1e3 * step.before_w:.2f} -> {1e3 * step.after_w:.2f} mW at {step.time_s:.0f} s"
        gain_error = smoothed_noise * math.sqrt(1.0 / max(before.stop - before.start, 1) + 1.0 / tail) \
            * math.sqrt(period_samples) / abs(delta_power)
        found.append(Discrepancy(f"T2 change per W over the hold (K/W), {label}", results["model"][0],
                                 results["measured"][0], _ratio(results["measured"][0] - results["model"][0],
                                                                gain_error)))
        slope_series = np.gradient(modelled_all[after], data.time_s[after])
        for index, percent in ((1, 10), (2, 63)):
            at_model, at_measured = results["model"][index], results["measured"][index]
            slope = float(np.interp(at_model, elapsed, np.abs(slope_series))) if math.isfinite(at_model) else 0.0
            time_error = smoothed_noise / slope if slope > 0 else math.inf
            found.append(Discrepancy(f"T2 time to {percent} % of the change (s), {label}", at_model, at_measured,
                                     _ratio(at_measured - at_model, time_error)))
    return found


def _crossing(elapsed: np.ndarray, fraction: np.ndarray, level: float) -> float:
    """First time the fraction of the change reaches ``level`` (interpolated), NaN if never."""
    above = np.flatnonzero(fraction >= level)
    if above.size == 0:
        return math.nan
    index = int(above[0])
    if index == 0:
        return float(elapsed[0])
    span = fraction[index] - fraction[index - 1]
    part = (level - fraction[index - 1]) / span if span else 0.0
    return float(elapsed[index - 1] + part * (elapsed[index] - elapsed[index - 1]))


def modulation_discrepancies(data: RecordData, replay: Replay, angular_frequency: float,
                             segments) -> list[Discrepancy]:
    """T2's response to heater modulation away from the line's harmonics: gain (K/W) and phase."""
    found = []
    for segment in segments:
        if segment.kind != "modulated":
            continue
        window = np.arange(segment.start_index, segment.stop_index)
        window = window[data.valid[window]]
        t = data.elapsed_s[window]
        heater = data.heater_w[window]
        frequency = _dominant_angular_frequency(t, heater)
        if frequency is None or min(abs(frequency - k * angular_frequency) for k in (1, 2, 3)) < 0.5:
            continue
        if segment.duration_s < 5 * 2.0 * math.pi / frequency:
            continue
        drive = fit_line(t, heater, frequency, trend_order=1)
        if drive.amplitude[0] <= 0.0:
            continue
        measured = fit_line(t, data.flange_K[window], frequency, trend_order=3)
        modelled = fit_line(t, replay.flange_K[window], frequency, trend_order=3)
        label = f"heater modulation at {frequency:.3f} rad/s, {segment.start_s:.0f}-{segment.stop_s:.0f} s"
        error = measured.amplitude_uncertainty[0] / drive.amplitude[0]
        found.append(Discrepancy(f"T2 response to the heater (K/W), {label}", modelled.amplitude[0] / drive.amplitude[0],
                                 measured.amplitude[0] / drive.amplitude[0],
                                 _ratio((measured.amplitude[0] - modelled.amplitude[0]) / drive.amplitude[0], error)))
        phase_model = wrap_phase(modelled.phase_rad[0] - drive.phase_rad[0])
        phase_measured = wrap_phase(measured.phase_rad[0] - drive.phase_rad[0])
        found.append(Discrepancy(f"T2 phase against the heater (rad), {label}", phase_model, phase_measured,
                                 _ratio(wrap_phase(phase_measured - phase_model),
                                        measured.amplitude_uncertainty[0] / max(measured.amplitude[0], 1e-300))))
    return found


def _dominant_angular_frequency(t: np.ndarray, values: np.ndarray) -> float | None:
    if t.size < 32:
        return None
    interval = float(np.median(np.diff(t)))
    spectrum = np.abs(np.fft.rfft((values - values.mean()) * np.hanning(values.size)))
    angular = 2.0 * math.pi * np.fft.rfftfreq(values.size, interval)
    spectrum[angular < 4.0 * math.pi / (t[-1] - t[0])] = 0.0
    if not spectrum.any():
        return None
    return float(angular[int(np.argmax(spectrum))])


def correlation_discrepancies(data: RecordData, replay: Replay) -> list[Discrepancy]:
    """Whiteness of the T2 residual and its cross-correlation with the heater (both against white noise)."""
    valid = data.valid
    residual = replay.flange_residual_K[valid]
    residual = residual - residual.mean()
    heater = data.heater_w[valid] - data.heater_w[valid].mean()
    count = residual.size
    scale = float(residual @ residual)
    if scale <= 0.0:
        return []
    autocorrelation = autocorrelation_at(residual, WHITENESS_LAGS)
    statistic = count * (count + 2) * float(np.sum(autocorrelation ** 2 / (count - np.asarray(WHITENESS_LAGS))))
    lags = len(WHITENESS_LAGS)
    found = [Discrepancy(f"T2 residual whiteness, Ljung-Box statistic over lags 1-{WHITENESS_LAGS[-1]} samples",
                         float(lags), statistic, max((statistic - lags) / math.sqrt(2.0 * lags), 0.0))]
    cross = cross_correlation_at(residual, heater, CROSS_CORRELATION_LAGS)
    if cross is not None:
        statistic = count * float(np.sum(cross ** 2))
        lags = len(CROSS_CORRELATION_LAGS)
        found.append(Discrepancy(
            f"T2 residual cross-correlation with the heater, N sum rho^2 over lags 0-{CROSS_CORRELATION_LAGS[-1]} samples",
            float(lags), statistic, max((statistic - lags) / math.sqrt(2.0 * lags), 0.0)))
    return found


def autocorrelation_at(values: np.ndarray, lags) -> np.ndarray:
    """Sample autocorrelation of a zero-mean series at the given lags."""
    scale = float(values @ values)
    return np.array([float(values[lag:] @ values[:-lag]) / scale for lag in lags])


def cross_correlation_at(residual: np.ndarray, heater: np.ndarray, lags) -> np.ndarray | None:
    """Correlation of the residual now with the heater ``lag`` samples earlier (zero-mean series)."""
    norm = math.sqrt(float(residual @ residual) * float(heater @ heater))
    if norm <= 0.0:
        return None
    lags = [lag for lag in lags if lag < residual.size // 2]
    return np.array([float(residual[lag:] @ heater[:residual.size - lag]) / norm for lag in lags])


def noise_discrepancies(model: CryostatModel, noise_rms_K, count: int) -> list[Discrepancy]:
    """Measured white noise of each thermometer against the model's sensor noise."""
    found = []
    for name, measured, nominal in (("T2", noise_rms_K[0], model.sensor_noise.flange_thermometer_rms_K),
                                    ("T5", noise_rms_K[1], model.sensor_noise.ptc_stage_thermometer_rms_K)):
        # the median of the Welch bins: relative standard error of the variance about 1.25 sqrt(2/N), half that on the rms
        error = measured * 1.25 / math.sqrt(2.0 * max(count, 1))
        found.append(Discrepancy(f"{name} white noise rms (K)", nominal, measured, _ratio(measured - nominal, error)))
    return found


def find_discrepancies(data: RecordData, model: CryostatModel, replay: Replay, noise_rms_K,
                       angular_frequency: float, segments: list[RecordSegment] | None = None) -> list[Discrepancy]:
    """Every discrepancy of this module between ``replay`` and the record, most significant first."""
    segments = find_segments(data.time_s, data.heater_w, data.setpoint_K) if segments is None else segments
    found = []
    found += residual_discrepancies(data, replay, noise_rms_K, segments)
    found += line_discrepancies(data, replay, angular_frequency, segments)
    found += harmonic_discrepancies(data, replay, angular_frequency)
    found += drift_discrepancy(data, model, angular_frequency)
    found += step_discrepancies(data, replay, noise_rms_K[0], angular_frequency, segments)
    found += modulation_discrepancies(data, replay, angular_frequency, segments)
    found += correlation_discrepancies(data, replay)
    found += noise_discrepancies(model, noise_rms_K, int(np.count_nonzero(data.valid)))
    return sorted(found, key=lambda d: -(d.significance if math.isfinite(d.significance) else 1e300))
