"""``cryod plot RECORD``: a quick look at any record, in one PNG.

Four panels over time: T2 with its setpoint (the band T2 spans within each
pixel column drawn, so the cooler's line shows as the band's width and the
slow part as its middle), T5, the heater power, and T2's part synchronous with
the cooler (harmonics 1-6 in 30 s blocks, the measure of the feedforward's
limit drawn beside it; blocks below the limit are marked and said why); a
fifth panel has T2's amplitude spectrum with the cooler's harmonics marked,
aliased ones at the frequency where the 12.5 Hz sampling puts them. The
cooler's frequency is the one the daemon tracks on T5
(:func:`cryod.cooler.phase.cooler_frequency_rad_s`).

The start-up (until the loop regulates a settled flange: :mod:`cryod.records.stretches`)
is shaded, faults are red lines and overruns ticks along the bottom of the time axes; the
spectrum is taken over the settled stretches between overruns and faults only, so neither
the start-up's transient nor an overrun's uneven sampling is in it.

The figure goes beside the record (``RECORD.png``) unless ``--out`` says
otherwise, and an existing file is kept unless ``--force`` (the record itself
always: :mod:`cryod.output_files`). Without RECORD, the record the running
daemon is writing grows between looks, and its quick look is drawn again in
place without ``--force``, as long as the file there is one ``cryod plot`` drew
of that record (the PNG says so in its text chunks, ``Software`` and ``Title``);
any other file there is kept unless ``--force``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from cryod.figure_files import HARMONICS, mark_cooler_harmonics
from cryod.output_files import output_file_refusal
from cryod.records.record import RecordFormatError, read_record
from cryod.records.stretches import settled, settled_stretches, startup_end_s
from cryod.regular_files import open_regular_file

#: Blocks over which the line's amplitude is fitted (s): about 50 cooler periods.
LINE_BLOCK_S = 30.0
#: Longest segment of the spectrum (s).
SPECTRUM_SEGMENT_S = 600.0
#: What the record's ``ff_limit_from`` says the limit came from, in words.
LIMIT_SOURCES = {"model": "controller's model", "learned": "learned plant"}
#: Events that cut the stretches the spectrum is taken over: the readings are unevenly spaced, or stop, there.
SPECTRUM_BREAKS = ("overrun", "fault", "stop", "resumed")
#: Pixel columns of the time axes; each gets T2's minimum and maximum.
COLUMNS = 1500
#: What a quick look's PNG names as the program that drew it (its ``Software`` text chunk).
SOFTWARE = "cryod plot"


def configure_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.description = "A quick look at a cryod-log record: temperatures, heater, cooler line, spectrum (PNG)."
    parser.add_argument("record", type=Path, nargs="?", default=None,
                        help="a cryod-log v1 file (.csv or .csv.gz); default: the record the running daemon "
                             "is writing (found as cryod ctl finds it, or at --socket)")
    parser.add_argument("--socket", type=Path, default=None, metavar="PATH",
                        help="without RECORD: the control socket of the daemon whose record to plot")
    parser.add_argument("--out", type=Path, default=None, metavar="PNG",
                        help="where the figure goes (default: beside the record, RECORD.png)")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing figure (without RECORD, the quick look cryod plot drew of the "
                             "record being written is drawn again without it)")
    parser.add_argument("--line-rad-s", type=float, default=10.83, metavar="RAD_S",
                        help="the cooler's nominal angular frequency, refined on T5 (default 10.83)")
    return parser


def run(args) -> int:
    running = args.record is None
    if running:
        from cryod.cli.running_record import running_record_path

        try:
            args.record = running_record_path(args.socket)
        except ConnectionError as error:
            print(f"cryod plot: {error}", file=sys.stderr)
            return 2
    out = args.out or args.record.with_name(args.record.name.removesuffix(".gz").removesuffix(".csv") + ".png")
    redraw = running and args.out is None and is_quick_look_of(out, args.record)
    refusal = output_file_refusal("cryod plot", out, force=args.force or redraw, inputs=[args.record])
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
    """The cooler's angular frequency (rad/s) as the daemon tracks it on T5, over the first hour at most
    (``nominal_rad_s`` when there is no line to lock to)."""
    from cryod.cooler.phase import cooler_frequency_rad_s

    usable = np.isfinite(time_s) & np.isfinite(ptc_stage_K)
    usable &= time_s <= time_s[usable][0] + 3600.0 if usable.any() else usable
    if usable.sum() < 100:
        return nominal_rad_s
    tracked = cooler_frequency_rad_s(time_s[usable], ptc_stage_K[usable], nominal_rad_s)
    return tracked if math.isfinite(tracked) else nominal_rad_s


def periodic_line_amplitudes(time_s: np.ndarray, flange_K: np.ndarray, rad_s: float, block_s: float = LINE_BLOCK_S,
                             harmonics: int = HARMONICS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T2's part synchronous with the cooler in blocks of ``block_s``: centres (s), amplitudes (K) and their noise (K).

    The amplitude is the root sum of squares of harmonics 1..``harmonics`` at ``rad_s`` (sqrt(2) x rms: the
    measure of ``ptc_periodic_amplitude_K`` and of the feedforward's limit); the noise is what the readings'
    scatter about the fit leaves in it, ``2 sigma sqrt(harmonics / n)`` for n readings in the block.
    """
    usable = np.isfinite(time_s) & np.isfinite(flange_K)
    t, y = time_s[usable], flange_K[usable]
    least = 4 * harmonics + 8
    if t.size < least:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    edges = np.arange(t[0], t[-1] + block_s, block_s)
    index = np.searchsorted(t, edges)
    centres, amplitudes, noises = [], [], []
    orders = np.arange(1, harmonics + 1)
    for start, stop in zip(index[:-1], index[1:]):
        if stop - start < least:
            continue
        tb, yb = t[start:stop], y[start:stop]
        angles = np.outer(rad_s * tb, orders)
        columns = np.column_stack([np.ones_like(tb), (tb - tb.mean()) / block_s, np.cos(angles), np.sin(angles)])
        solution, *_ = np.linalg.lstsq(columns, yb, rcond=None)
        residual = yb - columns @ solution
        centres.append(tb.mean())
        amplitudes.append(float(np.sqrt(np.sum(solution[2:] ** 2))))
        noises.append(2.0 * float(np.std(residual)) * math.sqrt(harmonics / tb.size))
    return np.array(centres), np.array(amplitudes), np.array(noises)


def cycle_mean(time_s: np.ndarray, values: np.ndarray, rad_s: float) -> np.ndarray:
    """``values`` averaged over the cooler cycles around each sample (a centred running mean over the samples of a
    few whole cycles; NaN where they are not all there): the heater's level, without the feedforward's waveform,
    which averages to nothing over whole cycles.

    Examples
    --------
    >>> t = np.arange(200) * 0.08
    >>> level = cycle_mean(t, 0.1 + 0.05 * np.sin(10.83 * t), 10.83)
    >>> bool(np.nanmax(np.abs(level - 0.1)) < 0.01)
    True
    """
    usable = np.isfinite(time_s) & np.isfinite(values)
    result = np.full(values.shape, np.nan)
    if usable.sum() < 3:
        return result
    step_s = float(np.median(np.diff(time_s[usable])))
    samples_per_cycle = 2.0 * math.pi / rad_s / step_s
    # whole cycles spanning a whole number of samples as nearly as a few cycles allow (7.25 samples a cycle at
    # 80 ms: 4 cycles are 29.0), so that the waveform leaves no remainder in the mean
    cycles = min(range(1, 9), key=lambda count: abs(count * samples_per_cycle - round(count * samples_per_cycle)))
    width = max(1, int(round(cycles * samples_per_cycle)))
    kernel = np.ones(width) / width
    filled = np.where(usable, values, 0.0)
    sums = np.convolve(filled, kernel, mode="same")
    counts = np.convolve(usable.astype(float), kernel, mode="same")
    whole = counts > 1.0 - 1e-9
    result[whole] = sums[whole]
    return result


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

    time_s = record.time_s
    duration = float(np.nanmax(time_s) - np.nanmin(time_s))
    scale, unit = (3600.0, "h") if duration > 3 * 3600 else (60.0, "min") if duration > 600 else (1.0, "s")
    hours = time_s / scale
    rad_s = cooler_frequency(time_s, record.ptc_stage_K, nominal_rad_s)
    startup_end = startup_end_s(time_s, record.flange_K, record.setpoint_K)
    marks = event_instants(record)

    regulated = np.isfinite(record.setpoint_K) & np.isfinite(record.flange_K)
    panels = 6 if regulated.sum() > 10 else 5
    figure, all_axes = plt.subplots(panels, 1, figsize=(11, 2.4 * panels + 1),
                                    gridspec_kw={"height_ratios": [3] + [2] * (panels - 2) + [3]})
    axes = list(all_axes)
    if panels == 6:
        error_axis = axes.pop(1)
        _draw_error(error_axis, time_s, record.flange_K - record.setpoint_K, regulated, scale,
                    settled(time_s, record.flange_K, record.setpoint_K))
    t2, low, high = _envelope(time_s, record.flange_K)
    axes[0].fill_between(t2 / scale, low, high, color="black", alpha=0.35, lw=0, label="T2, band within a pixel")
    middle = (low + high) / 2
    axes[0].plot(t2 / scale, middle, color="black", lw=0.8, label="T2, middle of the band")
    if np.isfinite(record.setpoint_K).any():
        axes[0].plot(hours, record.setpoint_K, color="tab:red", lw=1.0, ls="--", label="setpoint")
    axes[0].set_ylabel("T2 (K)")
    t5, low5, high5 = _envelope(time_s, record.ptc_stage_K)
    axes[1].fill_between(t5 / scale, low5, high5, color="tab:blue", alpha=0.4, lw=0, label="T5, band within a pixel")
    axes[1].set_ylabel("T5 (K)")
    axes[1].legend(loc="best", fontsize=8)
    th, lowh, highh = _envelope(time_s, record.heater_w)
    axes[2].fill_between(th / scale, lowh * 1e3, highh * 1e3, color="tab:orange", alpha=0.35, lw=0,
                         label="heater, its range within a pixel (the feedforward's waveform)")
    tm, mean_low, mean_high = _envelope(time_s, cycle_mean(time_s, record.heater_w, rad_s))
    axes[2].plot(tm / scale, (mean_low + mean_high) / 2 * 1e3, color="tab:brown", lw=1.2,
                 label="heater, mean over whole cooler cycles")
    axes[2].set_ylabel("heater (mW)")
    axes[2].legend(loc="best", fontsize=8)
    settled_rows = settled(time_s, record.flange_K, record.setpoint_K)
    _draw_line_against_limit(axes[3], record, rad_s, scale, settled_rows)
    time_axes = axes[:4] + ([error_axis] if panels == 6 else [])
    for axis in time_axes:
        axis.set_xlabel(f"time ({unit})")
        axis.grid(alpha=0.3)
    _mark_events(time_axes, marks, startup_end, time_s[0], scale)
    axes[0].legend(loc="best", fontsize=8)

    period = float(np.median(np.diff(time_s))) if time_s.size > 1 else 1.0
    stretches = settled_stretches(time_s, record.flange_K, record.setpoint_K,
                                  [instant for kind in SPECTRUM_BREAKS for instant in marks.get(kind, [])], period)
    spectrum = stretch_spectrum(record.flange_K, stretches, 1.0 / period)
    if spectrum is not None:
        frequency, amplitude, segment_s, used_s = spectrum
        axes[4].loglog(frequency[1:], amplitude[1:], color="black", lw=0.8, label="T2")
        mark_cooler_harmonics(axes[4], rad_s / (2.0 * math.pi), 1.0 / period)
        axes[4].set_xlabel("frequency (Hz)")
        axes[4].set_ylabel("T2 line amplitude (K)")
        over = "settled regulation" if startup_end is not None else "the record"
        axes[4].set_title(f"spectrum of T2 over {used_s:.0f} s of {over} ({segment_s:.0f} s segments, start-up and "
                          f"overruns left out); cooler harmonics dashed", fontsize=9)
        axes[4].grid(alpha=0.3, which="both")
    else:
        axes[4].set_axis_off()
        axes[4].set_title("no spectrum: no stretch of settled readings without overruns long enough", fontsize=9)
    figure.suptitle(f"{Path(record.source).name}: {duration / 3600:.2f} h, {len(record)} rows", fontsize=11)
    figure.tight_layout()
    figure.savefig(out, dpi=100, metadata={"Software": SOFTWARE, "Title": Path(record.source).name})
    plt.close(figure)
    return out


def is_quick_look_of(path: Path, record_path: Path) -> bool:
    """Whether ``path`` is a PNG that ``cryod plot`` drew of the record ``record_path`` (its text chunks
    ``Software`` and ``Title``, as Pillow, matplotlib's image library, reads them); False for anything else,
    a file missing or unreadable included."""
    from PIL import Image
    from PIL.PngImagePlugin import PngImageFile

    try:
        with open_regular_file(path) as file, Image.open(file, formats=["PNG"]) as image:
            text = dict(image.text) if isinstance(image, PngImageFile) else {}
    except (OSError, ValueError, SyntaxError):      # Pillow says SyntaxError of a damaged PNG's chunks
        return False
    return text.get("Software") == SOFTWARE and text.get("Title") == Path(record_path).name


def stretch_spectrum(values: np.ndarray, stretches: list[tuple[int, int]], sample_hz: float):
    """T2's amplitude spectrum (sine amplitude per bin, K) averaged over the clean stretches given.

    Welch's method over each stretch at least one segment long, the segments as long as the longest
    stretch allows (a power of two, :data:`SPECTRUM_SEGMENT_S` at most); each stretch weighs by its
    segments. Returns (frequency, amplitude, segment length s, time used s), or None when no stretch
    has 64 readings.
    """
    from scipy import signal

    longest = max((stop - start for start, stop in stretches), default=0)
    if longest < 64:
        return None
    segment = 2 ** int(math.log2(min(longest, SPECTRUM_SEGMENT_S * sample_hz)))
    total, weight, used = None, 0.0, 0
    for start, stop in stretches:
        if stop - start < segment:
            continue
        frequency, density = signal.welch(values[start:stop], fs=sample_hz, nperseg=segment, detrend="linear",
                                          scaling="spectrum")
        count = (stop - start) / segment
        total = density * count if total is None else total + density * count
        weight += count
        used += stop - start
    assert total is not None                # the longest stretch is at least a segment long
    return frequency, np.sqrt(2.0 * total / weight), segment / sample_hz, used / sample_hz


def _draw_line_against_limit(axis, record, rad_s: float, scale: float, settled_rows: np.ndarray) -> None:
    """T2's synchronous part, harmonics 1-6 in blocks, against the feedforward's limit in the same measure; the
    settled blocks below the limit marked, with why. A block not wholly settled is not compared: the limit holds
    for the mean power that balances the setpoint, and on the way there the heater's mean is another."""
    time_s = record.time_s
    centres, amplitudes, noises = periodic_line_amplitudes(time_s, record.flange_K, rad_s)
    axis.plot(centres / scale, amplitudes * 1e3, color="tab:purple", marker=".", ms=3, lw=0.8,
              label=f"T2 synchronous with the cooler ({rad_s / (2 * math.pi):.4f} Hz), harmonics 1-{HARMONICS}, "
                    f"{LINE_BLOCK_S:.0f} s blocks")
    limit = record.columns.get("ff_limit_K")
    if limit is not None and np.isfinite(limit).any() and centres.size:
        known = np.isfinite(limit)
        source = record.columns.get("ff_limit_from")
        sources = list(dict.fromkeys(LIMIT_SOURCES.get(str(value), str(value)) for value in source[known]
                                     if str(value))) if source is not None else []
        axis.plot(time_s / scale, limit * 1e3, color="gray", ls=":", lw=1.0,
                  label=f"feedforward's physical limit, harmonics 1-{HARMONICS} too"
                        + (f" (from the {', then the '.join(sources)})" if sources else ""))
        limit_at = np.interp(centres, time_s[known], limit[known], left=np.nan, right=np.nan)
        unsettled = time_s[~settled_rows & np.isfinite(record.flange_K)]
        nearest = np.searchsorted(unsettled, centres)
        gap = np.minimum(np.abs(unsettled[np.minimum(nearest, unsettled.size - 1)] - centres),
                         np.abs(unsettled[np.maximum(nearest - 1, 0)] - centres)) if unsettled.size else \
            np.full(centres.size, np.inf)
        limit_at[gap < LINE_BLOCK_S / 2] = np.nan            # the block holds unsettled readings: not compared
        below = amplitudes < limit_at
        beyond = below & (limit_at - amplitudes > 2.0 * noises)
        within = below & ~beyond
        if within.any():
            axis.plot(centres[within] / scale, amplitudes[within] * 1e3, "o", mfc="none", color="tab:orange", ms=5,
                      label="below the limit within twice the block's noise")
        if beyond.any():
            owner = " or ".join(f"{name}'s" for name in sources) or "controller's model's"
            axis.plot(centres[beyond] / scale, amplitudes[beyond] * 1e3, "o", mfc="none", color="tab:red", ms=5,
                      label=f"below the limit beyond the noise: the limit rests on the {owner} line, plant and "
                            f"mean power, and this cryostat differs")
        if below.any():
            axis.set_title(f"{int(below.sum())} of {int(np.isfinite(limit_at).sum())} settled blocks below the "
                           f"limit: {int(within.sum())} within twice their noise (median "
                           f"{np.median(noises[below]) * 1e6:.1f} µK), {int(beyond.sum())} beyond it "
                           f"(blocks not settled are not compared)", fontsize=8)
        else:
            axis.set_title(f"none of the {int(np.isfinite(limit_at).sum())} settled blocks below the limit (blocks "
                           f"not settled are not compared: the limit holds at the mean power of the balance)",
                           fontsize=8)
    axis.set_ylabel("synchronous T2 (mK)")
    axis.set_ylim(bottom=0)
    axis.legend(loc="best", fontsize=7)


def _draw_error(axis, time_s, error_K, regulated, scale: float, settled_rows) -> None:
    """T2 minus the setpoint (mK) where the loop regulated, scaled to where it spends its time once settled."""
    t, low, high = _envelope(np.where(regulated, time_s, np.nan), error_K)
    axis.fill_between(t / scale, low * 1e3, high * 1e3, color="black", alpha=0.35, lw=0,
                      label="T2 - setpoint, band within a pixel")
    axis.plot(t / scale, (low + high) / 2 * 1e3, color="black", lw=0.8, label="middle of the band")
    axis.axhline(0.0, color="tab:red", lw=0.8, ls="--")
    chosen = settled_rows if settled_rows.sum() > 10 else regulated
    inner = np.nanpercentile(error_K[chosen], [0.5, 99.5]) * 1e3
    span = max(inner[1] - inner[0], 1e-3)
    axis.set_ylim(inner[0] - 0.25 * span, inner[1] + 0.25 * span)
    axis.set_ylabel("T2 - setpoint (mK)")
    axis.set_title("where the loop regulated, scaled to the error once settled (the start-up's transient leaves "
                   "the axis)", fontsize=8)
    axis.legend(loc="best", fontsize=8)


def event_instants(record) -> dict[str, list[float]]:
    """The record's events by kind (``fault``, ``overrun``, ``stop``, ...): the instant of the row each precedes (s)."""
    time_s = record.time_s
    instants: dict[str, list[float]] = {}
    if not time_s.size:
        return instants
    for row, text in record.events:
        kind = text.removeprefix("event: ").split(":", 1)[0].strip()
        instants.setdefault(kind, []).append(float(time_s[min(row, time_s.size - 1)]))
    return instants


def _mark_events(axes, marks: dict[str, list[float]], startup_end: float | None, start_s: float,
                 scale: float) -> None:
    """The start-up shaded, faults as red lines, stops and reloads as grey ones, overruns as ticks along the bottom,
    on every time axis."""
    for axis in axes:
        first = axis is axes[0]
        if startup_end is not None and startup_end > start_s:
            axis.axvspan(start_s / scale, startup_end / scale, color="tab:green", alpha=0.08, lw=0,
                         label="start-up (left out of the spectrum)" if first else None)
        for kind, colour in (("fault", "tab:red"), ("stop", "gray"), ("reload", "gray")):
            for number, instant in enumerate(marks.get(kind, [])):
                axis.axvline(instant / scale, color=colour, lw=0.7, alpha=0.7,
                             label=kind if first and number == 0 else None)
        overruns = np.asarray(marks.get("overrun", []), dtype=float)
        if overruns.size:
            axis.plot(overruns / scale, np.zeros(overruns.size), "|", color="tab:red", ms=8, mew=0.8,
                      transform=axis.get_xaxis_transform(), clip_on=False,
                      label=f"overrun ({overruns.size}; left out of the spectrum)" if first else None)
