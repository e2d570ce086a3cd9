"""``cryod plot RECORD``: a quick look at any record, in one PNG.

Four panels over time: T2 with its setpoint (the band T2 spans within each
pixel column drawn, so the cooler's line shows as the band's width and the
slow part as its middle), T5, the heater power, and the cooler line's
amplitude on T2 (fitted at the cooler's frequency, found on T5, in 30 s
blocks); a fifth panel has T2's amplitude spectrum with the cooler's harmonics
marked, aliased ones at the frequency where the 12.5 Hz sampling puts them.
Faults and other events are marked on the time axes.

The figure goes beside the record (``RECORD.png``) unless ``--out`` says
otherwise, and an existing file is kept unless ``--force`` (the record itself
always: :mod:`cryod.output_files`).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from cryod.figure_files import mark_cooler_harmonics
from cryod.output_files import output_file_refusal
from cryod.records.record import RecordFormatError, read_record

#: Blocks over which the line's amplitude is fitted (s): about 50 cooler periods.
LINE_BLOCK_S = 30.0
#: Pixel columns of the time axes; each gets T2's minimum and maximum.
COLUMNS = 1500


def configure_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.description = "A quick look at a cryod-log record: temperatures, heater, cooler line, spectrum (PNG)."
    parser.add_argument("record", type=Path, help="a cryod-log v1 file (.csv or .csv.gz)")
    parser.add_argument("--out", type=Path, default=None, metavar="PNG",
                        help="where the figure goes (default: beside the record, RECORD.png)")
    parser.add_argument("--force", action="store_true", help="replace an existing figure")
    parser.add_argument("--line-rad-s", type=float, default=10.83, metavar="RAD_S",
                        help="the cooler's nominal angular frequency, refined on T5 (default 10.83)")
    return parser


def run(args) -> int:
    out = args.out or args.record.with_name(args.record.name.removesuffix(".gz").removesuffix(".csv") + ".png")
    refusal = output_file_refusal("cryod plot", out, force=args.force, inputs=[args.record])
    if refusal is not None:
        print(f"cryod plot: {refusal} (--out: another file)", file=sys.stderr)
        return 2
    try:
        record = read_record(args.record)
    except (OSError, RecordFormatError) as error:
        print(f"cryod plot: {error}", file=sys.stderr)
        return 2
    if len(record) < 2:
        print(f"cryod plot: {args.record}: {len(record)} row(s), nothing to plot", file=sys.stderr)
        return 2
    figure_path = plot_record(record, out, args.line_rad_s)
    print(figure_path)
    return 0


def cooler_frequency(time_s: np.ndarray, ptc_stage_K: np.ndarray, nominal_rad_s: float) -> float:
    """The cooler's angular frequency (rad/s) on T5 near ``nominal_rad_s`` (the first hour at most)."""
    from cryod.cooler.periodic import line_frequency

    usable = np.isfinite(time_s) & np.isfinite(ptc_stage_K)
    usable &= time_s <= time_s[usable][0] + 3600.0 if usable.any() else usable
    if usable.sum() < 100:
        return nominal_rad_s
    return line_frequency(time_s[usable], ptc_stage_K[usable], nominal_rad_s)


def line_amplitudes(time_s: np.ndarray, flange_K: np.ndarray, rad_s: float,
                    block_s: float = LINE_BLOCK_S) -> tuple[np.ndarray, np.ndarray]:
    """Centres (s) and amplitudes (K) of T2's line at ``rad_s``, fitted in blocks of ``block_s``."""
    usable = np.isfinite(time_s) & np.isfinite(flange_K)
    t, y = time_s[usable], flange_K[usable]
    if t.size < 20:
        return np.zeros(0), np.zeros(0)
    edges = np.arange(t[0], t[-1] + block_s, block_s)
    index = np.searchsorted(t, edges)
    centres, amplitudes = [], []
    for start, stop in zip(index[:-1], index[1:]):
        if stop - start < 20:
            continue
        tb, yb = t[start:stop], y[start:stop]
        scaled = (tb - tb.mean()) / block_s
        columns = np.column_stack([np.ones_like(tb), scaled, np.cos(rad_s * tb), np.sin(rad_s * tb)])
        solution, *_ = np.linalg.lstsq(columns, yb, rcond=None)
        centres.append(tb.mean())
        amplitudes.append(math.hypot(solution[2], solution[3]))
    return np.array(centres), np.array(amplitudes)


def _envelope(time_s: np.ndarray, values: np.ndarray, columns: int = COLUMNS):
    """Per pixel column: centre time, minimum and maximum of ``values`` (finite ones)."""
    usable = np.isfinite(time_s) & np.isfinite(values)
    t, v = time_s[usable], values[usable]
    if t.size <= 2 * columns:
        return t, v, v
    bins = np.minimum(((t - t[0]) / (t[-1] - t[0]) * columns).astype(int), columns - 1)
    starts = np.flatnonzero(np.r_[True, np.diff(bins) > 0])
    return (np.add.reduceat(t, starts) / np.diff(np.r_[starts, t.size]), np.minimum.reduceat(v, starts),
            np.maximum.reduceat(v, starts))


def plot_record(record, out: Path, nominal_rad_s: float = 10.83) -> Path:
    """Draw the quick look of ``record`` into ``out`` (PNG); returns ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy import signal

    time_s = record.time_s
    duration = float(np.nanmax(time_s) - np.nanmin(time_s))
    scale, unit = (3600.0, "h") if duration > 3 * 3600 else (60.0, "min") if duration > 600 else (1.0, "s")
    hours = time_s / scale
    rad_s = cooler_frequency(time_s, record.ptc_stage_K, nominal_rad_s)

    regulated = np.isfinite(record.setpoint_K) & np.isfinite(record.flange_K)
    panels = 6 if regulated.sum() > 10 else 5
    figure, all_axes = plt.subplots(panels, 1, figsize=(11, 2.4 * panels + 1),
                                    gridspec_kw={"height_ratios": [3] + [2] * (panels - 2) + [3]})
    axes = list(all_axes)
    if panels == 6:
        error_axis = axes.pop(1)
        _draw_error(error_axis, time_s, record.flange_K - record.setpoint_K, regulated, scale)
    t2, low, high = _envelope(time_s, record.flange_K)
    axes[0].fill_between(t2 / scale, low, high, color="black", alpha=0.35, lw=0, label="T2, band within a pixel")
    middle = (low + high) / 2
    axes[0].plot(t2 / scale, middle, color="black", lw=0.8, label="T2, middle of the band")
    if np.isfinite(record.setpoint_K).any():
        axes[0].plot(hours, record.setpoint_K, color="tab:red", lw=1.0, ls="--", label="setpoint")
    axes[0].set_ylabel("T2 (K)")
    axes[0].legend(loc="best", fontsize=8)
    t5, low5, high5 = _envelope(time_s, record.ptc_stage_K)
    axes[1].fill_between(t5 / scale, low5, high5, color="tab:blue", alpha=0.4, lw=0, label="T5, band within a pixel")
    axes[1].set_ylabel("T5 (K)")
    axes[1].legend(loc="best", fontsize=8)
    th, lowh, highh = _envelope(time_s, record.heater_w)
    axes[2].fill_between(th / scale, lowh * 1e3, highh * 1e3, color="tab:orange", alpha=0.5, lw=0,
                         label="heater, band within a pixel")
    axes[2].plot(th / scale, (lowh + highh) / 2 * 1e3, color="tab:orange", lw=0.8)
    axes[2].set_ylabel("heater (mW)")
    axes[2].legend(loc="best", fontsize=8)
    centres, amplitudes = line_amplitudes(time_s, record.flange_K, rad_s)
    axes[3].plot(centres / scale, amplitudes * 1e3, color="tab:purple", marker=".", ms=3, lw=0.8,
                 label=f"T2 at the cooler's {rad_s / (2 * math.pi):.3f} Hz, {LINE_BLOCK_S:.0f} s blocks")
    if "ff_limit_K" in record.columns and np.isfinite(record.columns["ff_limit_K"]).any():
        axes[3].plot(hours, record.columns["ff_limit_K"] * 1e3, color="gray", ls=":", lw=1.0,
                     label="feedforward's physical limit (all harmonics)")
    axes[3].set_ylabel("cooler line on T2 (mK)")
    axes[3].set_ylim(bottom=0)
    axes[3].legend(loc="best", fontsize=8)
    time_axes = axes[:4] + ([error_axis] if panels == 6 else [])
    for axis in time_axes:
        axis.set_xlabel(f"time ({unit})")
        axis.grid(alpha=0.3)
    _mark_events(record, time_axes, scale)

    usable = np.isfinite(record.flange_K) & np.isfinite(time_s)
    if usable.sum() > 64:
        sample_hz = 1.0 / float(np.median(np.diff(time_s[usable])))
        segment = int(min(usable.sum(), 2 ** int(math.log2(max(64, min(usable.sum(), 600 * sample_hz))))))
        frequency, density = signal.welch(record.flange_K[usable], fs=sample_hz, nperseg=segment,
                                          detrend="linear", scaling="spectrum")
        amplitude = np.sqrt(2.0 * density)                 # sine amplitude of a line (K)
        axes[4].loglog(frequency[1:], amplitude[1:], color="black", lw=0.8, label="T2")
        mark_cooler_harmonics(axes[4], rad_s / (2.0 * math.pi), sample_hz)
        axes[4].set_xlabel("frequency (Hz)")
        axes[4].set_ylabel("T2 line amplitude (K)")
        axes[4].set_title(f"spectrum of T2 (sine amplitude per bin, {segment / sample_hz:.0f} s segments); "
                          f"cooler harmonics dashed", fontsize=9)
        axes[4].grid(alpha=0.3, which="both")
    figure.suptitle(f"{Path(record.source).name}: {duration / 3600:.2f} h, {len(record)} rows", fontsize=11)
    figure.tight_layout()
    figure.savefig(out, dpi=100)
    plt.close(figure)
    return out


def _draw_error(axis, time_s, error_K, regulated, scale: float) -> None:
    """T2 minus the setpoint (mK) where the loop regulated, scaled to where it spends its time."""
    t, low, high = _envelope(np.where(regulated, time_s, np.nan), error_K)
    axis.fill_between(t / scale, low * 1e3, high * 1e3, color="black", alpha=0.35, lw=0,
                      label="T2 - setpoint, band within a pixel")
    axis.plot(t / scale, (low + high) / 2 * 1e3, color="black", lw=0.8, label="middle of the band")
    axis.axhline(0.0, color="tab:red", lw=0.8, ls="--")
    settled = error_K[regulated][int(0.2 * regulated.sum()):]      # past the first fifth: the settled part
    inner = np.nanpercentile(settled, [0.5, 99.5]) * 1e3
    span = max(inner[1] - inner[0], 1e-3)
    axis.set_ylim(inner[0] - 0.25 * span, inner[1] + 0.25 * span)
    axis.set_ylabel("T2 - setpoint (mK)")
    axis.set_title("where the loop regulated, scaled to the error after the first fifth of that time "
                   "(a start-up transient leaves the axis)", fontsize=8)
    axis.legend(loc="best", fontsize=8)


def _mark_events(record, axes, scale: float) -> None:
    """Faults as red lines, other stops and reloads as grey ones, on every time axis."""
    time_s = record.time_s
    labelled = set()
    for row, text in record.events:
        kind = text.removeprefix("event: ").split(":", 1)[0].strip()
        if kind not in ("fault", "stop", "reload") or not time_s.size:
            continue
        instant = time_s[min(row, time_s.size - 1)] / scale
        colour = "tab:red" if kind == "fault" else "gray"
        for axis in axes:
            axis.axvline(instant, color=colour, lw=0.7, alpha=0.7,
                         label=kind if kind not in labelled and axis is axes[0] else None)
        labelled.add(kind)
    if labelled:
        axes[0].legend(loc="best", fontsize=8)
