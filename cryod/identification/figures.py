"""Figures of an identification (PNG, matplotlib with the Agg backend): data, fit and residuals of each fit.

* ``fit_T2.png`` (``fit_T2_<k>.png`` for record k of several): the
  heater-to-flange-thermometer fit. T2 measured and fitted, the heater, and the
  residual; T2 and the residual are averaged over one cooler period so the
  step's shape shows (the line itself is fitted, and drawn in ``fit_line.png``).
* ``fit_T5.png``: the heater-to-PTC-stage fit, the same way (T5 with its line removed).
* ``fit_line.png``: a few cooler periods of T5 and T2 on the record's most settled
  stretch (:func:`settled_window`), measured and fitted (the line gain from T5 to T2),
  with the residual.
* ``terms.png``: the residual rms of each number of terms tried, against the
  noise, and the BIC (the count chosen marked).
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (the backend must be chosen first)
import numpy as np  # noqa: E402
from scipy import ndimage  # noqa: E402

from cryod.figure_files import save_figure, thin  # noqa: E402
from cryod.identification.model_fit import ChannelResult, ModelIdentification  # noqa: E402


def _period_average(values: np.ndarray, samples: int) -> np.ndarray:
    finite = np.isfinite(values)
    filled = np.where(finite, values, np.nanmean(values))
    return ndimage.uniform_filter1d(filled, max(samples, 1), mode="nearest")


def _channel_figure(result: ModelIdentification, channel: ChannelResult, index: int, title: str, quantity: str,
                    path: Path) -> Path:
    data = result.records[index]
    elapsed = data.elapsed_s
    samples = int(round(2.0 * math.pi / result.line.angular_frequency_rad_s / data.sample_interval_s))
    measured = channel.channel.records[index].target_K
    fitted = channel.prediction_K[index]
    residual = channel.residual_K[index]
    figure, (top, middle, bottom) = plt.subplots(3, 1, figsize=(9.0, 8.0), sharex=True,
                                                 gridspec_kw={"height_ratios": [3, 1, 2]})
    t, m, f = thin(elapsed, _period_average(measured, samples), _period_average(fitted, samples))
    top.plot(t, m, color="black", lw=1.2, label=f"{quantity} measured (cooler-period average)")
    top.plot(t, f, color="tab:red", lw=1.0, ls="--", label=f"fit: {channel.fit.count} term(s), "
             + ", ".join(f"{tau:.4g} s" for tau in channel.fit.time_constants_s))
    top.set_ylabel(f"{quantity} (K)")
    top.set_title(title)
    top.legend(loc="best", fontsize=8)
    top.grid(alpha=0.3)
    t, heater = thin(elapsed, data.heater_w)
    middle.step(t, heater * 1e3, where="post", color="tab:orange")
    middle.set_ylabel("heater (mW)")
    middle.grid(alpha=0.3)
    t, raw, smooth = thin(elapsed, residual, _period_average(residual, samples))
    unit, scale = ("µK", 1e6) if np.nanmax(np.abs(residual)) < 2e-3 else ("mK", 1e3)
    bottom.plot(t, raw * scale, color="0.7", lw=0.4, label="residual")
    bottom.plot(t, smooth * scale, color="tab:blue", lw=1.0, label="residual, cooler-period average")
    noise = result.noise_rms_K[0 if quantity == "T2" else 1]
    bottom.axhline(2 * noise * scale, color="tab:green", lw=0.8, ls=":", label=f"2 x noise rms ({noise * scale:.3g} {unit})")
    bottom.axhline(-2 * noise * scale, color="tab:green", lw=0.8, ls=":")
    bottom.set_ylabel(f"measured - fit ({unit})")
    bottom.set_xlabel("time since the record's start (s)")
    bottom.legend(loc="best", fontsize=8)
    bottom.grid(alpha=0.3)
    return save_figure(figure, path)


def settled_window(elapsed_s: np.ndarray, flange_K: np.ndarray, period_samples: int, span_s: float) -> np.ndarray:
    """Where T2 has settled most: the ``span_s`` of the record over which T2's slow part (averaged over one
    cooler period) moves least, the latest of those within a tenth of the least; a boolean mask of the samples.

    A record that starts with T2 on its way to a setpoint, or whose heater changes at every tick (closed loop),
    still shows its line on a stretch where it is not hidden under T2's drift.

    Examples
    --------
    >>> t = np.arange(0.0, 600.0, 0.08)
    >>> flange = 5.0 - 0.04 * np.exp(-t / 60.0) + 0.001 * np.sin(10.83 * t)
    >>> window = settled_window(t, flange, 7, 3.5)
    >>> bool(t[window][0] > 500.0), round(float(np.ptp(t[window])), 1)
    (True, 3.4)
    """
    slow = _period_average(flange_K, period_samples)
    interval_s = float(np.median(np.diff(elapsed_s))) if elapsed_s.size > 1 else 0.0
    step = max(int(round(span_s / interval_s)), 1) if interval_s > 0.0 else slow.size
    if slow.size <= step:
        return np.ones(slow.size, dtype=bool)
    starts = np.arange(0, slow.size - step + 1, max(step // 2, 1))
    windows = np.lib.stride_tricks.sliding_window_view(slow, step)[starts]
    drift = np.ptp(windows, axis=1)
    best = starts[np.flatnonzero(drift <= 1.1 * np.nanmin(drift) + 1e-12)[-1]]
    window = np.zeros(slow.size, dtype=bool)
    window[best:best + step] = True
    return window


def line_figure(result: ModelIdentification, path: Path, periods: float = 6.0) -> Path:
    """A few cooler periods of T5 and T2 where T2 has settled most in the first record (:func:`settled_window`)."""
    data = result.records[0]
    elapsed = data.elapsed_s
    span = periods * 2.0 * math.pi / result.line.angular_frequency_rad_s
    samples = int(round(2.0 * math.pi / result.line.angular_frequency_rad_s / data.sample_interval_s))
    window = settled_window(elapsed, data.flange_K, samples, span)
    flange, stage = result.flange, result.stage
    stage_line = data.ptc_stage_K - stage.channel.records[0].target_K          # the fitted line in T5
    flange_measured = flange.channel.records[0].target_K
    figure, (top, middle, bottom) = plt.subplots(3, 1, figsize=(9.0, 7.5), sharex=True)
    t = elapsed[window]
    top.plot(t, (data.ptc_stage_K[window] - np.nanmean(data.ptc_stage_K[window])) * 1e3, "k.", ms=3,
             label="T5 measured")
    top.plot(t, (stage_line[window] - np.nanmean(stage_line[window])) * 1e3, color="tab:red", lw=1.0,
             label="T5 line fitted")
    top.set_ylabel("T5 - mean (mK)")
    top.set_title("The cooler's line: T5 measured and fitted; T2 and its fit through the line gain")
    top.legend(fontsize=8, loc="upper right")
    top.grid(alpha=0.3)
    mean = np.nanmean(flange_measured[window])
    middle.plot(t, (flange_measured[window] - mean) * 1e3, "k.", ms=3, label="T2 measured")
    middle.plot(t, (flange.prediction_K[0][window] - mean) * 1e3, color="tab:red", lw=1.0, label="T2 fitted")
    middle.set_ylabel("T2 - mean (mK)")
    middle.legend(fontsize=8, loc="upper right")
    middle.grid(alpha=0.3)
    bottom.plot(t, flange.residual_K[0][window] * 1e6, color="tab:blue", lw=0.8, label="T2 residual")
    bottom.set_ylabel("T2 measured - fit (µK)")
    bottom.set_xlabel("time since the record's start (s)")
    bottom.legend(fontsize=8, loc="upper right")
    bottom.grid(alpha=0.3)
    return save_figure(figure, path)


def terms_figure(result: ModelIdentification, path: Path) -> Path:
    """Residual rms and BIC against the number of terms, for both heater paths."""
    figure, axes = plt.subplots(1, 2, figsize=(9.0, 3.8))
    for axis, (channel, noise, name) in zip(axes, ((result.flange, result.noise_rms_K[0], "T2"),
                                                  (result.stage, result.noise_rms_K[1], "T5"))):
        counts = [row["terms"] for row in channel.selection.table]
        rms = np.array([row["residual_rms_K"] for row in channel.selection.table]) / noise
        held = np.array([row["held_out_rms_K"] for row in channel.selection.table]) / noise
        axis.plot(counts, rms, "o-", color="black", label="residual rms / noise")
        if np.all(np.isfinite(held)):
            axis.plot(counts, held, "s--", color="tab:blue", label="held-out rms / noise")
        if np.nanmax(held if np.all(np.isfinite(held)) else rms) > 3.0 * np.nanmin(rms):
            axis.set_yscale("log")
        axis.axvline(channel.fit.count, color="tab:red", lw=1.0, ls=":", label=f"chosen: {channel.fit.count}")
        axis.set_xticks(counts)
        axis.set_xlabel("first-order terms")
        axis.set_ylabel("rms in units of the noise")
        axis.set_title(f"heater to {name}: {channel.fit.count} term(s) chosen by the BIC", fontsize=9)
        axis.legend(fontsize=8)
        axis.grid(alpha=0.3, which="both")
    return save_figure(figure, path)


def figure_files(record_count: int) -> dict[str, str]:
    """The file of each figure of an identification from ``record_count`` records, by name.

    >>> list(figure_files(2).values())
    ['fit_T2_1.png', 'fit_T5_1.png', 'fit_T2_2.png', 'fit_T5_2.png', 'fit_line.png', 'terms.png']
    """
    files = {}
    for index in range(record_count):
        suffix = f"_{index + 1}" if record_count > 1 else ""
        files[f"fit_T2{suffix}"] = f"fit_T2{suffix}.png"
        files[f"fit_T5{suffix}"] = f"fit_T5{suffix}.png"
    return {**files, "fit_line": "fit_line.png", "terms": "terms.png"}


def make_figures(result: ModelIdentification, out: Path) -> dict[str, Path]:
    """Write every figure (:func:`figure_files`) into ``out``; returns their paths by name."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {name: out / file_name for name, file_name in figure_files(len(result.records)).items()}
    made = {}
    several = len(result.records) > 1
    for index in range(len(result.records)):
        suffix = f"_{index + 1}" if several else ""
        made[f"fit_T2{suffix}"] = _channel_figure(
            result, result.flange, index, "Heater to flange thermometer (G2 G1): T2 measured and fitted", "T2",
            files[f"fit_T2{suffix}"])
        made[f"fit_T5{suffix}"] = _channel_figure(
            result, result.stage, index, "Heater to PTC stage (G3): T5 less its line, measured and fitted", "T5",
            files[f"fit_T5{suffix}"])
    made["fit_line"] = line_figure(result, files["fit_line"])
    made["terms"] = terms_figure(result, files["terms"])
    return made


__all__ = ["figure_files", "make_figures", "line_figure", "terms_figure"]
