"""What a model leaves in a record, described in numbers with their significance.

For ``unexplained``, and for whatever the causes named leave, ``cryod analyze``
describes the residual of the extended model (measured less replayed):

* **spectral peaks** of the T2 and T5 residuals (Welch, Hann windows of up
  to 2^14 samples): frequency, amplitude, significance against the local
  floor (the running median of the spectrum; with K averaged windows a bin's
  ratio to the floor is chi-square with 2K degrees of freedom over 2K: the
  tail probability times the number of bins, as a normal deviate), and whether
  the peak is at one of the cooler's harmonics (folded by the sampling) or at a
  sideband of one (amplitude or phase modulation of the line, at the
  sideband's offset);
* **slow drift**: the residual's spectrum below 0.02 Hz, a straight line in
  log-log (level at 1 mHz, slope: about -2 a random walk, -1 a 1/f process,
  0 white), and its excess over the white floor in standard deviations;
* **cross-correlations** on means over two line periods (which cancel the
  line): with the heater at positive lags (the heater before the residual: an
  error of a heater path) and negative lags (the residual before the heater:
  feedback, a disturbance the loop answers), with T5, and with the line's
  envelope in T5 (30 s blocks); each with its 99 % band for independent
  series, ``2.58 sqrt(sum_k r_aa(k) r_bb(k) / N)`` (Bartlett), and the band
  the largest over all the lags must pass to count (the normal quantile of
  1 % over the number of lags in place of 2.58);
* **where**: the residual's rms (in noise units) in each segment of the record
  and the blocks where it is largest;
* **MATLAB's** ``resid``: the residual's autocorrelation with the 99 % band
  ``2.58 / sqrt(N)`` and its cross-correlation with the input (the heater) at
  negative and positive lags with the band above (``resid.png``).

Examples
--------
>>> classify_peak(1.7236, 1.7236, 12.5, 0.0005)
'harmonic 1'
>>> classify_peak(1.7236 + 1 / 600, 1.7236, 12.5, 0.0005)
'sideband of harmonic 1 at +0.00167 Hz (period 600 s): modulation of the line'
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, signal, stats

from cryod.analysis.segments import find_segments
from cryod.figure_files import folded_frequency

#: Welch window length (samples) at most; peaks at least this many sigma over the floor; this many listed.
WELCH_SAMPLES = 2 ** 14
PEAK_SIGMA = 6.0
MOST_PEAKS = 8
#: Bins either side of a peak that its window leaks into.
LEAKAGE_BINS = 4
#: Sidebands: a peak within this of a harmonic (Hz) but not on it.
SIDEBAND_SPAN_HZ = 0.05
HARMONIC_ORDERS = (1, 2, 3, 4, 5)
#: Drift: the spectrum below this frequency (Hz), level quoted at the reference frequency.
DRIFT_BELOW_HZ = 0.02
DRIFT_REFERENCE_HZ = 1e-3
#: Correlations: lags up to this (s); 99 % bands.
LONGEST_LAG_S = 300.0
BAND_FACTOR = 2.58
#: Lags of the resid-style figure (in means over two line periods).
RESID_LAGS = 60
ENVELOPE_BLOCK_S = 30.0


def classify_peak(frequency_hz: float, line_hz: float, sample_hz: float, resolution_hz: float) -> str:
    """Where a peak lies against the cooler's harmonics (folded by the sampling)."""
    offsets = [(order, frequency_hz - float(folded_frequency(order * line_hz, sample_hz))) for order in HARMONIC_ORDERS]
    order, offset = min(offsets, key=lambda pair: abs(pair[1]))         # the nearest, the lowest order of a tie
    if abs(offset) <= 2.0 * resolution_hz:
        return f"harmonic {order}"
    if abs(offset) <= SIDEBAND_SPAN_HZ:
        return (f"sideband of harmonic {order} at {offset:+.3g} Hz (period {1.0 / abs(offset):.0f} s): "
                "modulation of the line")
    return NOT_AT_HARMONICS


#: A peak away from every harmonic of the cooler and its sidebands.
NOT_AT_HARMONICS = "not at the cooler's harmonics"


@dataclass(frozen=True)
class SpectralPeak:
    thermometer: str
    frequency_hz: float
    amplitude_K: float
    significance: float
    relation: str


@dataclass(frozen=True)
class Drift:
    thermometer: str
    level_K2_per_Hz: float
    slope: float
    kind: str
    significance: float


@dataclass(frozen=True)
class CrossCorrelation:
    """Largest correlation at positive and at negative lags (s; positive: the other signal first).

    ``band`` is the 99 % band at one lag (what the resid figure draws); ``band_over_lags`` the 99 % band of the
    largest of all the lags looked at (the same Bartlett scale, at the normal quantile of 1 % over their number):
    the largest of some hundred correlations of independent series passes the one-lag band by chance.
    """

    other: str
    positive_lag_s: float
    positive: float
    negative_lag_s: float
    negative: float
    band: float
    band_over_lags: float

    @property
    def significant(self) -> bool:
        """Whether the largest correlation is beyond what independent series give at any of the lags (99 %)."""
        return max(abs(self.positive), abs(self.negative)) > self.band_over_lags


@dataclass
class ResidualSignature:
    """The description of a residual (see the module doc); :meth:`as_dict` is the JSON's ``residual_signature``."""

    peaks: list = field(default_factory=list)
    drifts: list = field(default_factory=list)
    correlations: list = field(default_factory=list)
    segments: list = field(default_factory=list)
    worst_blocks: list = field(default_factory=list)
    resid: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"spectral_peaks": [vars(peak) for peak in self.peaks], "drift": [vars(drift) for drift in self.drifts],
                "cross_correlations": [{**vars(item), "significant": item.significant}
                                       for item in self.correlations],
                "segments": self.segments, "largest_blocks": self.worst_blocks,
                "resid": {key: [float(v) for v in value] if isinstance(value, np.ndarray) else value
                          for key, value in self.resid.items()}}

    def sentences(self) -> list[str]:
        """The signature in words, most telling first."""
        found = []
        for peak in self.peaks[:4]:
            found.append(f"{peak.thermometer} residual peak at {peak.frequency_hz:.4g} Hz, "
                         f"{peak.amplitude_K * 1e6:.3g} µK ({peak.significance:.0f} sigma): {peak.relation}")
        for drift in self.drifts:
            if drift.significance >= PEAK_SIGMA:
                found.append(f"{drift.thermometer} residual drifts: {drift.kind} (slope {drift.slope:.2f}, "
                             f"{drift.level_K2_per_Hz:.3g} K^2/Hz at {DRIFT_REFERENCE_HZ * 1e3:g} mHz, "
                             f"{drift.significance:.0f} sigma over the white floor)")
        for item in self.correlations:
            if item.significant:
                side = (f"{item.other} first by {item.positive_lag_s:.0f} s: {item.positive:+.2f}"
                        if abs(item.positive) >= abs(item.negative) else
                        f"the residual first by {-item.negative_lag_s:.0f} s: {item.negative:+.2f}")
                found.append(f"T2 residual correlates with {item.other} ({side}; 99 % band over the lags "
                             f"{item.band_over_lags:.2f})")
        return found


def _welch(values: np.ndarray, sample_hz: float):
    length = min(values.size, WELCH_SAMPLES)
    frequencies, power = signal.welch(values, sample_hz, window="hann", nperseg=length, scaling="spectrum",
                                      detrend="linear")
    windows = max(1.0, values.size / length)      # overlapping windows are not independent: count them whole
    return frequencies, power, windows


#: A residual's peak where the heater has one too.
AT_HEATER_LINE = "where the heater has a line too: a heater path's error, or the loop answering a disturbance"


def spectral_peaks(residual: np.ndarray, name: str, sample_hz: float, line_hz: float,
                   heater_lines_hz=()) -> list[SpectralPeak]:
    """Peaks of a residual's spectrum above its local floor (see the module doc); a peak away from the cooler's
    harmonics but at one of ``heater_lines_hz`` (Hz) says so."""
    frequencies, power, windows = _welch(residual, sample_hz)
    floor = ndimage.median_filter(power, size=51, mode="nearest")
    dof = 2.0 * windows
    # the running median is the floor's median: the mean of a chi-square over its degrees of freedom is larger
    floor = np.maximum(floor / stats.chi2.median(dof) * dof, 1e-300)
    # a bin's power over the floor is chi-square with 2K degrees of freedom over 2K; its tail probability,
    # times the number of bins looked at, as a normal deviate
    tail = stats.chi2.logsf(power / floor * dof, dof) + math.log(power.size)
    sigma = stats.norm.isf(np.exp(np.minimum(tail, math.log(0.5))))
    sigma = np.where(np.isfinite(sigma), sigma, 40.0)
    resolution = frequencies[1] - frequencies[0]
    lowest = 4.0 / (residual.size / sample_hz)
    candidates, _ = signal.find_peaks(sigma)
    found: list[SpectralPeak] = []
    taken: list[int] = []
    for index in candidates[np.argsort(-power[candidates])]:
        if sigma[index] < PEAK_SIGMA or frequencies[index] < max(lowest, DRIFT_BELOW_HZ / 4) \
                or index >= frequencies.size - LEAKAGE_BINS:                       # the Nyquist bin's own statistics
            continue
        if any(abs(index - other) <= LEAKAGE_BINS for other in taken):      # a stronger peak's window leakage
            continue
        taken.append(index)
        # a sinusoid's power spreads over the Hann window's 1.5 bins of equivalent noise bandwidth
        amplitude = math.sqrt(2.0 * float(power[max(index - 2, 0):index + 3].sum()) / 1.5)
        relation = classify_peak(float(frequencies[index]), line_hz, sample_hz, resolution)
        if relation == NOT_AT_HARMONICS and any(abs(frequencies[index] - line) <= 2.0 * resolution
                                                for line in heater_lines_hz):
            relation = AT_HEATER_LINE
        found.append(SpectralPeak(name, float(frequencies[index]), amplitude, float(sigma[index]), relation))
        if len(found) == MOST_PEAKS:
            break
    return found


def heater_frequencies_hz(data, line_hz: float) -> list[float]:
    """Frequencies (Hz) of the heater's own spectral lines away from the cooler's harmonics (a modulation, the loop's
    answer to a periodic disturbance), by the rule of :func:`spectral_peaks`."""
    heater = data.heater_w[data.valid]
    peaks = spectral_peaks(heater - float(np.mean(heater)), "heater", 1.0 / data.sample_interval_s, line_hz)
    return [peak.frequency_hz for peak in peaks if peak.relation == NOT_AT_HARMONICS]


def drift(residual: np.ndarray, name: str, sample_interval_s: float, noise_rms_K: float) -> Drift:
    """The residual's spectrum below :data:`DRIFT_BELOW_HZ`: slope, level and excess over the white floor."""
    frequencies, density = signal.periodogram(residual, 1.0 / sample_interval_s, window="hann", detrend="linear")
    low = (frequencies > 0.0) & (frequencies <= DRIFT_BELOW_HZ)
    white = 2.0 * noise_rms_K ** 2 * sample_interval_s            # one-sided density of the white noise
    if np.count_nonzero(low) < 3:
        return Drift(name, math.nan, math.nan, "too short to tell", 0.0)
    slope, intercept = np.polyfit(np.log10(frequencies[low]), np.log10(np.maximum(density[low], 1e-300)), 1)
    level = float(10.0 ** (intercept + slope * math.log10(DRIFT_REFERENCE_HZ)))
    excess = (float(np.mean(density[low])) / white - 1.0) * math.sqrt(np.count_nonzero(low))
    kind = ("random walk (1/f^2)" if slope < -1.5 else "1/f" if slope < -0.5 else "white")
    return Drift(name, level, float(slope), kind, float(excess))


def period_means(values: np.ndarray, samples: int) -> np.ndarray:
    """Means over consecutive windows of ``samples`` (the last partial one dropped)."""
    count = values.size // samples
    return values[:count * samples].reshape(count, samples).mean(axis=1)


def correlation(first: np.ndarray, second: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """Correlation of ``first`` now with ``second`` ``lag`` windows earlier (negative: later), zero-mean input."""
    norm = math.sqrt(float(first @ first) * float(second @ second))
    values = []
    for lag in lags:
        if lag >= 0:
            values.append(float(first[lag:] @ second[:second.size - lag]))
        else:
            values.append(float(first[:lag] @ second[-lag:]))
    return np.array(values) / norm if norm > 0 else np.zeros(len(lags))


def bartlett_band(first: np.ndarray, second: np.ndarray, longest: int) -> float:
    """99 % band of the cross-correlation of two independent series with these autocorrelations."""
    lags = np.arange(-longest, longest + 1)
    product = correlation(first, first, lags) * correlation(second, second, lags)
    return BAND_FACTOR * math.sqrt(max(float(product.sum()), 1.0) / first.size)


def cross_correlation(residual: np.ndarray, other: np.ndarray, name: str, window_s: float) -> CrossCorrelation:
    """Largest correlation at positive and negative lags, with its band (series of means over ``window_s``)."""
    longest = max(1, min(int(LONGEST_LAG_S / window_s), residual.size // 4))
    lags = np.arange(-longest, longest + 1)
    values = correlation(residual, other, lags)
    positive, negative = lags >= 0, lags <= 0
    best_positive = int(np.argmax(np.abs(values[positive])))
    best_negative = int(np.argmax(np.abs(values[negative])))
    band = bartlett_band(residual, other, longest)
    over_lags = band / BAND_FACTOR * float(stats.norm.isf(0.005 / lags.size))
    return CrossCorrelation(name, float(lags[positive][best_positive] * window_s),
                            float(values[positive][best_positive]),
                            float(lags[negative][best_negative] * window_s),
                            float(values[negative][best_negative]), band, over_lags)


def line_envelope(data, line) -> np.ndarray:
    """The fundamental's amplitude in T5 in blocks of :data:`ENVELOPE_BLOCK_S`, at every sample (K)."""
    elapsed, stage = data.elapsed_s, data.ptc_stage_K
    valid = data.valid
    phase = line.cycle.phase_rad(elapsed) if line.cycle is not None else line.angular_frequency_rad_s * elapsed
    samples = max(int(ENVELOPE_BLOCK_S / data.sample_interval_s), 8)
    centres, amplitudes = [], []
    for start in range(0, elapsed.size - samples + 1, samples):
        part = slice(start, start + samples)
        keep = valid[part]
        if np.count_nonzero(keep) < samples // 2:
            continue
        design = np.column_stack([np.sin(phase[part][keep]), np.cos(phase[part][keep]), np.ones(np.count_nonzero(keep)),
                                  elapsed[part][keep] - elapsed[part][keep].mean()])
        solution, *_ = np.linalg.lstsq(design, stage[part][keep], rcond=None)
        centres.append(float(elapsed[part].mean()))
        amplitudes.append(math.hypot(solution[0], solution[1]))
    if len(centres) < 2:
        return np.full(elapsed.size, np.nan)
    return np.interp(elapsed, centres, amplitudes)


def describe_residual(analysis, replay=None) -> ResidualSignature:
    """The signature of ``replay``'s residual (default: the extended model's) in ``analysis``'s record."""
    data = analysis.data
    replay = replay if replay is not None else analysis.extended_replay
    valid = data.valid
    interval = data.sample_interval_s
    sample_hz = 1.0 / interval
    line_hz = analysis.base_line.angular_frequency_rad_s / (2.0 * math.pi)
    noise = analysis.noise_rms_K
    flange = np.where(valid, replay.flange_residual_K, 0.0)
    stage = np.where(valid, replay.ptc_stage_residual_K, 0.0)
    found = ResidualSignature()
    heater_lines = heater_frequencies_hz(data, line_hz)
    for name, residual, rms in (("T2", flange, noise[0]), ("T5", stage, noise[1])):
        found.peaks += spectral_peaks(residual[valid], name, sample_hz, line_hz, heater_lines)
        found.drifts.append(drift(residual[valid], name, interval, rms))
    found.peaks.sort(key=lambda peak: -peak.significance)
    samples = max(1, int(round(2.0 * 2.0 * math.pi / analysis.base_line.angular_frequency_rad_s / interval)))
    window_s = samples * interval
    means = {name: period_means(values, samples) for name, values in (
        ("residual", flange), ("heater", data.heater_w), ("T5", np.where(valid, data.ptc_stage_K, 0.0)),
        ("envelope", line_envelope(data, analysis.base_line)))}
    means = {name: values - np.nanmean(values) for name, values in means.items()}
    residual = means.pop("residual")
    for name, values in means.items():
        if np.all(np.isfinite(values)) and float(values @ values) > 0.0:
            found.correlations.append(cross_correlation(residual, values, {"envelope": "the line's envelope in T5"}
                                                        .get(name, name), window_s))
    for segment in find_segments(data.time_s, data.heater_w, data.setpoint_K):
        inside = valid & (data.time_s >= segment.start_s) & (data.time_s <= segment.stop_s)
        if np.count_nonzero(inside) > 10:
            found.segments.append({"kind": segment.kind, "from_s": segment.start_s, "to_s": segment.stop_s,
                                   "T2_rms_in_noise": float(np.sqrt(np.mean((flange[inside] / noise[0]) ** 2))),
                                   "T5_rms_in_noise": float(np.sqrt(np.mean((stage[inside] / noise[1]) ** 2)))})
    found.worst_blocks = _worst_blocks(data, flange, stage, noise)
    heater = means["heater"]
    lags = np.arange(0, min(RESID_LAGS, residual.size // 4) + 1)
    cross_lags = np.arange(-lags[-1], lags[-1] + 1)
    found.resid = {"lag_s": lags * window_s, "autocorrelation": correlation(residual, residual, lags),
                   "autocorrelation_band": BAND_FACTOR / math.sqrt(residual.size),
                   "cross_lag_s": cross_lags * window_s,
                   "cross_correlation_with_heater": correlation(residual, heater, cross_lags),
                   "cross_correlation_band": bartlett_band(residual, heater, int(lags[-1])),
                   "window_s": window_s}
    return found


def _worst_blocks(data, flange, stage, noise, count: int = 3) -> list[dict]:
    from cryod.analysis.record_data import block_length_s

    length = block_length_s(data.duration_s)
    index = np.floor(data.elapsed_s / length).astype(int)
    chi = np.where(data.valid, (flange / noise[0]) ** 2 + (stage / noise[1]) ** 2, 0.0)
    sums = np.bincount(index, chi)
    terms = np.maximum(2 * np.bincount(index, data.valid.astype(float)), 1.0)
    per_term = sums / terms
    order = np.argsort(-per_term)[:count]
    return [{"from_s": float(block * length), "to_s": float((block + 1) * length),
             "chi_square_per_term": float(per_term[block])} for block in order]


__all__ = ["AT_HEATER_LINE", "NOT_AT_HARMONICS", "ResidualSignature", "classify_peak", "describe_residual",
           "heater_frequencies_hz", "spectral_peaks"]
