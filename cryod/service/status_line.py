"""A live status line on the terminal while the daemon runs.

One line, redrawn twice a second by tqdm on its own thread: state, T2 and its
error, T5, the heater's level (while regulating its power over the last 10 cooler cycles, without
the feedforward's waveform), the cooler line's amplitude on T2 (all its harmonics), faults,
alarms raised; for a run
of known length (``--duration``) a progress bar with the simulated time done
and the time left. It is on only when the stream is a terminal: under systemd,
in a pipe or a file, nothing is written.

Examples
--------
>>> format_status({"state": "closed", "T2_K": 5.0000123, "error_K": 1.23e-5, "T5_K": 3.41234,
...                "heater_W": 0.1132, "line_amplitude_K": 5.5e-4, "faults": {}, "lateness_ms": 0.2})
'closed | T2 5.000012 K (+12.3 µK) | T5 3.4123 K | heater 113.2 mW | line 550 µK | lateness 0.2 ms'
"""

from __future__ import annotations

import math
import os
import threading

from tqdm import tqdm

from cryod.service.live_view import LiveView

#: Wall time between redraws (s).
REFRESH_S = 0.5
#: Width drawn on a terminal that does not tell its size (a fresh pseudo-terminal says 0 columns).
DEFAULT_COLUMNS = 150


def _columns(stream) -> int:
    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return 0


def _microkelvin(value_K: float, signed: bool = False) -> str:
    if not math.isfinite(value_K):
        return "-"
    micro = value_K * 1e6
    if abs(micro) >= 1000:
        return f"{value_K * 1e3:{'+' if signed else ''}.3f} mK"
    return f"{micro:{'+' if signed else ''}.{1 if abs(micro) < 100 else 0}f} µK"


def format_status(snapshot: dict) -> str:
    """The status text of a :meth:`LiveView.snapshot`, with units."""
    parts = [str(snapshot.get("state", ""))]
    flange = snapshot.get("T2_K", math.nan)
    if math.isfinite(flange):
        error = snapshot.get("error_K", math.nan)
        parts.append(f"T2 {flange:.6f} K" + (f" ({_microkelvin(error, signed=True)})" if math.isfinite(error) else ""))
    stage = snapshot.get("T5_K", math.nan)
    if math.isfinite(stage):
        parts.append(f"T5 {stage:.4f} K")
    heater = snapshot.get("heater_W", math.nan)
    level = snapshot.get("heater_mean_W", math.nan)        # the heater's level, without the waveform
    if math.isfinite(heater) and math.isfinite(level) and str(snapshot.get("state", "")).startswith("closed"):
        heater = level
    parts.append(f"heater {heater * 1e3:.1f} mW" if math.isfinite(heater) else "heater UNKNOWN")
    line = snapshot.get("line_amplitude_K", math.nan)
    if math.isfinite(line):
        parts.append(f"line {_microkelvin(line)}")
    lateness = snapshot.get("lateness_ms", math.nan)
    if math.isfinite(lateness):
        parts.append(f"lateness {lateness:.1f} ms")
    overruns = snapshot.get("overruns", 0)
    if overruns:
        parts.append(f"overruns {overruns}")
    speed = snapshot.get("achieved_speed")
    if speed is not None and math.isfinite(speed):
        parts.append(f"speed {speed:.1f}x")
    faults = sum(snapshot.get("faults", {}).values())
    if faults:
        parts.append(f"faults {faults} (last: {snapshot.get('last_fault')})")
    if snapshot.get("alarms"):
        parts.append(f"ALARM {', '.join(snapshot['alarms'])} (cryod ctl alarms)")
    return " | ".join(parts)


class _AboveTheLine:
    """A text stream for the log whose lines go above the status line (through ``tqdm.write``)."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text: str) -> int:
        tqdm.write(text, file=self.stream, end="")
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:
        return True


class StatusLine:
    """Draws :func:`format_status` of a :class:`LiveView` on a terminal until stopped.

    Parameters
    ----------
    view : LiveView
    stream : file
        Where to draw (the daemon's stderr); nothing is drawn unless it is a terminal.
    duration_s : float, optional
        Length of the run in clock seconds, for the progress bar and the time left.
    refresh_s : float
        Wall time between redraws (s).
    speed : callable, optional
        Returns the simulated seconds per real second achieved lately (a paced dry run's clock).
    """

    def __init__(self, view: LiveView, stream, duration_s: float | None = None, refresh_s: float = REFRESH_S,
                 speed=None):
        self.view = view
        self.speed = speed
        self.stream = stream
        self.duration_s = duration_s
        self.refresh_s = refresh_s
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.enabled = bool(getattr(stream, "isatty", lambda: False)())

    @property
    def log_stream(self):
        """Where the daemon's log should write so its lines go above the status line (the stream
        itself when there is no status line)."""
        return _AboveTheLine(self.stream) if self.enabled else self.stream

    def start(self) -> None:
        """Start drawing (does nothing when the stream is not a terminal)."""
        if not self.enabled:
            return
        self._thread = threading.Thread(target=self._draw, name="cryod-status-line", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Draw once more and leave the last line on the terminal."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def _draw(self) -> None:
        total = self.duration_s
        bar_format = ("{desc} {percentage:3.0f}% |{bar:12}| {n:.0f}/{total:.0f} s, left {remaining}"
                      if total else "{desc} | {n:.0f} s")
        sized = _columns(self.stream) > 0
        with tqdm(total=total, desc="starting", file=self.stream, bar_format=bar_format, dynamic_ncols=sized, leave=True,
                  ncols=None if sized else DEFAULT_COLUMNS, nrows=None if sized else 24,
                  mininterval=0.0, position=0) as bar:
            while True:
                stopping = self._stop.wait(self.refresh_s)
                snapshot = self.view.snapshot()
                if self.speed is not None:
                    snapshot["achieved_speed"] = self.speed()
                elapsed = snapshot["elapsed_s"]
                bar.n = min(elapsed, total) if total else elapsed
                bar.set_description_str(format_status(snapshot), refresh=False)
                bar.refresh()
                if stopping:
                    return
