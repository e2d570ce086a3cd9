"""The figures of an analysis (PNG, matplotlib with the Agg backend).

* ``overview.png``: T2 measured and replayed (base and extended model), the
  residuals, the heater; segments shaded. Smoothed over one line period so the
  slow behaviour is visible; the line itself is in ``ptc_line.png``.
* ``residual_spectrum.png``: spectra of the T2 and T5 residuals of both
  models, with the measured noise floor and the cooler's harmonics labelled
  (those above the Nyquist frequency where the sampling folds them).
* ``ptc_line.png``: a few line periods of T2, measured and replayed, where the
  base model misses the line most.
* ``candidates.png``: each candidate's held-out improvement and significance.
* ``steps.png``: T2 around each heater step, measured and replayed.
* ``correlation.png``: the T2 residual's autocorrelation and cross-correlation
  with the heater, against the bands of white noise.
* ``resid.png``: the extended model's T2 residual as MATLAB's ``resid``
  shows it (:mod:`cryod.analysis.residual_signature`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (the backend must be chosen first)
import numpy as np  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from scipy import ndimage, signal  # noqa: E402

from cryod.analysis.cause_search.results import Analysis  # noqa: E402
from cryod.analysis.decision import CANDIDATE_SIGMA  # noqa: E402
from cryod.analysis.discrepancies import (  # noqa: E402
    CROSS_CORRELATION_LAGS,
    WHITENESS_LAGS,
    autocorrelation_at,
    cross_correlation_at,
)
from cryod.analysis.segments import find_steps  # noqa: E402
from cryod.figure_files import folded_frequency, mark_cooler_harmonics, save_figure, thin  # noqa: E402

COLOURS = {"measured": "black", "base": "tab:red", "extended": "tab:blue"}
SEGMENT_COLOURS = {"closed loop": "tab:green", "hold": "tab:gray", "modulated": "tab:orange"}




def _period_samples(analysis: Analysis) -> int:
    return max(1, int(round(2.0 * math.pi / analysis.base_line.angular_frequency_rad_s
                            / analysis.data.sample_interval_s)))


def _smooth(values: np.ndarray, samples: int) -> np.ndarray:
    filled = np.where(np.isfinite(values), values, np.nanmean(values))
    return ndimage.uniform_filter1d(filled, samples, mode="nearest")


def _extended_label(analysis: Analysis) -> str:
    """What the extended model adds: the recalibration and the causes named."""
    added = analysis.cause_names if analysis.cause not in ("none", "unexplained") else []
    return " + ".join((["recalibrated"] if analysis.recalibrated else []) + added) or analysis.cause


def _shade_segments(axis, analysis: Analysis, segments, legend: bool = False) -> None:
    """Shade each segment by its kind; with ``legend``, add the kinds present to the axis' legend."""
    for segment in segments:
        axis.axvspan(segment.start_s, segment.stop_s, color=SEGMENT_COLOURS[segment.kind], alpha=0.08, lw=0)
    if legend:
        handles, labels = axis.get_legend_handles_labels()
        for kind in dict.fromkeys(segment.kind for segment in segments):
            handles.append(Patch(color=SEGMENT_COLOURS[kind], alpha=0.25, lw=0))
            labels.append(f"segment: {kind}")
        axis.legend(handles, labels, loc="best", fontsize=8)


#: How each curve is drawn: the measurement on top, solid; the models under it, dashed.
CURVE_STYLE: dict[str, dict[str, Any]] = {"measured": {"lw": 1.3, "zorder": 4}, "base": {"lw": 0.9, "ls": "--", "zorder": 3},
               "extended": {"lw": 0.9, "ls": ":", "zorder": 3}}


def overview(analysis: Analysis, segments, path: Path) -> Path:
    data = analysis.data
    samples = _period_samples(analysis)
    base, extended = analysis.base_replay, analysis.extended_replay
    figure, axes = plt.subplots(3, 1, figsize=(11, 8.5), sharex=True, gridspec_kw={"height_ratios": [2, 2, 1]})
    t = data.time_s
    curves = [("measured", data.flange_K), ("base", base.flange_K)]
    if analysis.extended:
        curves.append(("extended", extended.flange_K))
    for name, values in curves:
        axes[0].plot(*thin(t, _smooth(values, samples)), color=COLOURS[name], **CURVE_STYLE[name],
                     label={"measured": "measured", "base": "base model",
                            "extended": f"extended ({_extended_label(analysis)})"}[name])
    axes[0].set_ylabel("T2 (K), line averaged out")
    for name, replay in (("base", base), ("extended", extended)):
        if name == "extended" and not analysis.extended:
            continue
        axes[1].plot(*thin(t, 1e3 * _smooth(replay.flange_residual_K, samples)), color=COLOURS[name], lw=0.8,
                     label=f"{'base' if name == 'base' else 'extended'} model: measured - replayed")
    noise = 1e3 * analysis.noise_rms_K[0] / math.sqrt(samples)
    axes[1].axhspan(-3 * noise, 3 * noise, color="k", alpha=0.1, label="+-3 x noise (smoothed)")
    axes[1].set_ylabel("T2 residual (mK)")
    axes[1].legend(loc="best", fontsize=8)
    axes[2].plot(*thin(t, 1e3 * data.heater_w), color="tab:purple", lw=0.8)
    axes[2].set_ylabel("heater (mW)")
    axes[2].set_xlabel("time (s)")
    for index, axis in enumerate(axes):
        _shade_segments(axis, analysis, segments, legend=index == 0)
    axes[0].set_title(f"{Path(data.source).name}: cause {analysis.cause}")
    return save_figure(figure, path)


def residual_spectrum(analysis: Analysis, path: Path) -> Path:
    data = analysis.data
    sampling = 1.0 / data.sample_interval_s
    modulation_hz = record_heater_modulation_hz(data, analysis.base_line.angular_frequency_rad_s / (2.0 * math.pi))
    figure, axes = plt.subplots(2, 1, figsize=(10, 7.5), sharex=True)
    for axis, name, noise, base_values, extended_values in (
            (axes[0], "T2", analysis.noise_rms_K[0], analysis.base_replay.flange_residual_K,
             analysis.extended_replay.flange_residual_K),
            (axes[1], "T5", analysis.noise_rms_K[1], analysis.base_replay.ptc_stage_residual_K,
             analysis.extended_replay.ptc_stage_residual_K)):
        for label, values, colour in (("base model", base_values, COLOURS["base"]),
                                      (f"extended ({_extended_label(analysis)})", extended_values, COLOURS["extended"])):
            if label.startswith("extended") and not analysis.extended:
                continue
            values = values[data.valid]
            frequency, density = signal.welch(values - values.mean(), fs=sampling,
                                              nperseg=int(min(4096, max(256, values.size // 8))))
            axis.loglog(frequency[1:], np.sqrt(density[1:]), color=colour, lw=0.8, label=label)
        axis.axhline(noise * math.sqrt(2.0 / sampling), color="k", ls="--", lw=0.8, label="measured white noise")
        mark_cooler_harmonics(axis, analysis.base_line.angular_frequency_rad_s / (2.0 * math.pi), sampling)
        if modulation_hz is not None:
            axis.axvline(modulation_hz, color="tab:orange", lw=0.8, ls="--", alpha=0.7)
            axis.annotate(f"heater modulation {modulation_hz:.3g} Hz", (modulation_hz, 0.03),
                          xycoords=("data", "axes fraction"), rotation=90, fontsize=7, va="bottom", ha="right")
        axis.set_ylabel(f"{name} residual (K/sqrt(Hz))")
        axis.legend(loc="best", fontsize=8)
    axes[1].set_xlabel("frequency (Hz); dashed: the cooler's harmonics (purple: folded by the sampling)")
    return save_figure(figure, path)


def record_heater_modulation_hz(data, cooler_hz: float) -> float | None:
    """The frequency of a modulation imposed on the heater while the loop was open (Hz), or None.

    Only the open-loop rows (no setpoint) are looked at: regulating, the heater follows the
    controller (PI's answer to the cooler's line and the noise, the feedforward's waveform), and
    a peak of its spectrum there is no modulation anyone imposed.
    """
    open_loop = data.valid & ~np.isfinite(data.setpoint_K)
    return heater_modulation_hz(data.heater_w[open_loop], 1.0 / data.sample_interval_s, cooler_hz)


def heater_modulation_hz(heater_w: np.ndarray, sample_hz: float, cooler_hz: float) -> float | None:
    """The frequency of a heater modulation in the record (Hz), or None: the strongest of the heater
    spectrum's peaks above 50 mHz that stand 30 times over their neighbourhood, the cooler's harmonics
    (which the feedforward plays) left out."""
    if heater_w.size < 512:
        return None
    frequency, density = signal.welch(heater_w - heater_w.mean(), fs=sample_hz,
                                      nperseg=int(min(4096, heater_w.size // 4)))
    level = np.log10(np.maximum(density, np.max(density) * 1e-15 + 1e-30))
    peaks, _ = signal.find_peaks(level, prominence=math.log10(30.0))
    harmonics = [folded_frequency(order * cooler_hz, sample_hz) for order in range(1, 7)]
    best = None
    for peak in peaks:
        near_cooler = min(abs(frequency[peak] - h) for h in harmonics) < 0.03
        if frequency[peak] > 0.05 and not near_cooler and (best is None or density[peak] > best[1]):
            best = (float(frequency[peak]), density[peak])      # the strongest: a square wave's fundamental
    return None if best is None else best[0]


def ptc_line(analysis: Analysis, path: Path) -> Path:
    """Five line periods where the base model's residual at the line is largest; slow parts removed."""
    data = analysis.data
    period = 2.0 * math.pi / analysis.base_line.angular_frequency_rad_s
    samples = _period_samples(analysis)
    residual = np.where(data.valid, analysis.base_replay.flange_residual_K, 0.0)
    at_line = residual - ndimage.uniform_filter1d(residual, samples, mode="nearest")
    power = ndimage.uniform_filter1d(at_line ** 2, 5 * samples, mode="nearest")
    centre = int(np.argmax(power))
    window = (data.time_s >= data.time_s[centre] - 2.5 * period) & (data.time_s <= data.time_s[centre] + 2.5 * period)
    slow = _smooth(data.flange_K, samples)[window]
    figure, axis = plt.subplots(figsize=(10, 4.5))
    t = data.time_s[window]
    axis.plot(t, 1e3 * (data.flange_K[window] - slow), "o", ms=3, color=COLOURS["measured"], label="T2 measured")
    axis.plot(t, 1e3 * (analysis.base_replay.flange_K[window] - slow), "-", color=COLOURS["base"],
              label="T2 base model")
    if analysis.extended:
        axis.plot(t, 1e3 * (analysis.extended_replay.flange_K[window] - slow), "-", color=COLOURS["extended"],
                  label=f"T2 extended ({analysis.cause})")
    axis.set_ylabel("T2 less its one-period average (mK)")
    axis.set_xlabel("time (s)")
    twin = axis.twinx()
    twin.plot(t, data.ptc_stage_K[window], color="tab:cyan", lw=0.8, alpha=0.7, label="T5 measured")
    twin.set_ylabel("T5 (K)", color="tab:cyan")
    axis.legend(loc="upper left", fontsize=8)
    axis.set_title("PTC line where the base model misses it most")
    return save_figure(figure, path)


def candidates(analysis: Analysis, path: Path) -> Path:
    names = list(analysis.scores)
    improvement = [analysis.scores[name].improvement for name in names]
    significance = [analysis.scores[name].significance for name in names]
    figure, axis = plt.subplots(figsize=(10, 4.5))
    colours = ["tab:blue" if name == analysis.cause else "tab:gray" for name in names]
    axis.barh(names, improvement, color=colours)
    axis.set_xscale("symlog", linthresh=25.0)
    axis.axvline(analysis.decision.base.excess, color="tab:red", ls="--", lw=1.0,
                 label="base model's held-out excess over noise")
    for index, (value, sigma) in enumerate(zip(improvement, significance)):
        axis.annotate(f"{sigma:.3g} sigma", (value, index), xytext=(4, -3), textcoords="offset points", fontsize=8)
    axis.set_xlabel("held-out improvement over the base model (noise-variance units, symlog)")
    axis.set_title(f"candidates (blue: named; counts from {CANDIDATE_SIGMA:g} sigma)")
    axis.legend(loc="upper left", fontsize=8)
    return save_figure(figure, path)


def steps(analysis: Analysis, segments, path: Path) -> Path | None:
    data = analysis.data
    found = find_steps(data.time_s, data.heater_w, segments)
    if not found:
        return None
    samples = _period_samples(analysis)
    columns = min(len(found), 3)
    rows = int(math.ceil(len(found) / columns))
    figure, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.4 * rows), squeeze=False)
    for axis, step in zip(axes.flat, found):
        window = slice(max(step.before.start_index, step.index - 60 * samples), step.after.stop_index)
        t = data.time_s[window] - step.time_s
        axis.plot(t, 1e3 * _smooth(data.flange_K, samples)[window], color=COLOURS["measured"],
                  **CURVE_STYLE["measured"], label="measured")
        axis.plot(t, 1e3 * _smooth(analysis.base_replay.flange_K, samples)[window], color=COLOURS["base"],
                  **CURVE_STYLE["base"], label="base")
        if analysis.extended:
            axis.plot(t, 1e3 * _smooth(analysis.extended_replay.flange_K, samples)[window],
                      color=COLOURS["extended"], **CURVE_STYLE["extended"], label="extended")
        axis.set_title(f"{1e3 * step.before_w:.1f} -> {1e3 * step.after_w:.1f} mW at {step.time_s:.0f} s", fontsize=9)
        axis.set_xlabel("time after the step (s)")
        axis.set_ylabel("T2 (mK)")
    for axis in list(axes.flat)[len(found):]:
        axis.set_visible(False)
    axes.flat[0].legend(fontsize=8)
    return save_figure(figure, path)


def correlation(analysis: Analysis, path: Path) -> Path:
    data = analysis.data
    valid = data.valid
    interval = data.sample_interval_s
    figure, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name, replay, colour in (("base", analysis.base_replay, COLOURS["base"]),
                                 ("extended", analysis.extended_replay, COLOURS["extended"])):
        if name == "extended" and not analysis.extended:
            continue
        residual = replay.flange_residual_K[valid] - np.mean(replay.flange_residual_K[valid])
        heater = data.heater_w[valid] - np.mean(data.heater_w[valid])
        axes[0].plot(np.asarray(WHITENESS_LAGS) * interval, autocorrelation_at(residual, WHITENESS_LAGS), "o-",
                     color=colour, ms=3, label=f"{name} model")
        cross = cross_correlation_at(residual, heater, CROSS_CORRELATION_LAGS)
        if cross is not None:
            axes[1].semilogx((np.asarray(CROSS_CORRELATION_LAGS[:cross.size]) + 0.5) * interval, cross, "o-",
                             color=colour, ms=3, label=f"{name} model")
    band = 3.0 / math.sqrt(max(int(np.count_nonzero(valid)), 1))
    for axis in axes:
        axis.axhspan(-band, band, color="k", alpha=0.1, label="+-3/sqrt(N): white noise")
        axis.legend(fontsize=8)
    axes[0].set_xlabel(f"lag (s; one sample is {interval * 1e3:.0f} ms)")
    axes[0].set_ylabel("T2 residual autocorrelation")
    axes[1].set_xlabel("lag behind the heater (s, + half a sample for the log axis)")
    axes[1].set_ylabel("correlation with the heater")
    return save_figure(figure, path)


def resid(analysis: Analysis, path: Path) -> Path | None:
    """MATLAB's ``resid`` view of the extended model's T2 residual (means over two line periods)."""
    signature = analysis.residual_signature
    if signature is None or not signature.resid:
        return None
    found = signature.resid
    figure, axes = plt.subplots(2, 1, figsize=(8, 6))
    axes[0].bar(found["lag_s"], found["autocorrelation"], width=0.6 * found["window_s"], color=COLOURS["extended"])
    band = found["autocorrelation_band"]
    axes[0].axhspan(-band, band, color="k", alpha=0.1, label="99 % band (white residual)")
    axes[0].set_ylabel("autocorrelation of the residual")
    axes[0].set_xlabel("lag (s)")
    axes[1].bar(found["cross_lag_s"], found["cross_correlation_with_heater"], width=0.6 * found["window_s"],
                color=COLOURS["extended"])
    band = found["cross_correlation_band"]
    axes[1].axhspan(-band, band, color="k", alpha=0.1, label="99 % band (independent of the heater)")
    axes[1].set_ylabel("cross-correlation, heater to residual")
    axes[1].set_xlabel("lag (s; positive: the heater first)")
    for axis in axes:
        axis.axhline(0.0, color="k", lw=0.5)
        axis.legend(fontsize=8)
    return save_figure(figure, path)


#: The file of each figure, by name.
FIGURE_FILES = {"overview": "overview.png", "residual_spectrum": "residual_spectrum.png", "ptc_line": "ptc_line.png",
                "candidates": "candidates.png", "correlation": "correlation.png", "steps": "steps.png",
                "resid": "resid.png"}


def make_figures(analysis: Analysis, segments, directory: Path) -> dict[str, Path]:
    """All figures into ``directory`` (the files of :data:`FIGURE_FILES`); returns {name: path} of those made."""
    directory = Path(directory)
    files = {name: directory / file_name for name, file_name in FIGURE_FILES.items()}
    made = {
        "overview": overview(analysis, segments, files["overview"]),
        "residual_spectrum": residual_spectrum(analysis, files["residual_spectrum"]),
        "ptc_line": ptc_line(analysis, files["ptc_line"]),
        "candidates": candidates(analysis, files["candidates"]),
        "correlation": correlation(analysis, files["correlation"]),
    }
    step_figure = steps(analysis, segments, files["steps"])
    if step_figure is not None:
        made["steps"] = step_figure
    resid_figure = resid(analysis, files["resid"])
    if resid_figure is not None:
        made["resid"] = resid_figure
    return made
