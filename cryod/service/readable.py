"""Numbers for people: a status value with its unit and the precision it deserves.

Keys carry their unit as a suffix (``T2_K``, ``heater_W``, ``lateness_ms_p99``);
:func:`readable` prints the value in that unit at a precision the measurement
supports, :func:`rounded` rounds a JSON object's numbers to that precision
(temperatures and powers to 7 significant digits, 1 µK at 5 K as the DMMs resolve
it, other figures to 6), so ``0.5000000000000001`` W reads ``500.000 mW`` and is
written ``0.5``.

Examples
--------
>>> readable("T2_K", 5.0000123), readable("ff_line_K", 5.5e-4), readable("heater_W", 0.5000000000000001)
('5.000012 K', '550.0 µK', '500.000 mW')
>>> readable("lateness_ms_p99", 0.0412), readable("ramp_K_per_min", 0.5), readable("state", "closed")
('0.04 ms', '0.5 K/min', 'closed')
>>> readable("ff_phase_rad", 5082.042), readable("ff_locked", 1)
("5.228 rad (the cooler's phase within its cycle, 0 to 2 pi)", 'yes')
>>> rounded({"heater_W": 0.5000000000000001, "rms_K": 1.3511053281048303e-05, "ticks": 3750})
{'heater_W': 0.5, 'rms_K': 1.351105e-05, 'ticks': 3750}
"""

from __future__ import annotations

import math

#: Below this a temperature is a difference or an amplitude, shown in µK or mK.
SMALL_K = 0.1


def _unit(key: str) -> str:
    for suffix in ("_K_per_min", "_rad_s", "_rad", "_K", "_W", "_ms", "_s", "_ohm", "_A", "_MB"):
        if key.endswith(suffix) or f"{suffix}_" in key:
            return suffix[1:]
    return ""


def _in_words(key: str, value: float) -> str | None:
    """The feedforward's status values in the lab's words (None: the key is read by its unit)."""
    if key == "ff_phase_rad":             # the tracker counts whole cycles too: the phase within one is what means
        return f"{value % (2.0 * math.pi):.3f} rad (the cooler's phase within its cycle, 0 to 2 pi)"
    if key == "ff_locked":
        return "yes" if value else "no (the waveform waits for the lock)"
    if key == "ff_scale":
        return f"{100.0 * value:.0f} % (the waveform faded in)"
    if key == "ff_W":
        return f"{value * 1e3:.3f} mW (the waveform's part, added to PI's: negative is normal)"
    return None


def readable(key: str, value) -> str:
    """``value`` of status key ``key`` as text with its unit (the feedforward's few in words)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    words = _in_words(key, value)
    if words is not None:
        return words
    unit = _unit(key)
    if unit == "K":
        if abs(value) < SMALL_K:
            return f"{value * 1e6:.1f} µK" if abs(value) < 1e-3 else f"{value * 1e3:.4f} mK"
        return f"{value:.6f} K"
    if unit == "W":
        return f"{value * 1e3:.3f} mW"
    if unit == "K_per_min":
        return f"{value:g} K/min"
    if unit == "rad_s":
        return f"{value:.4f} rad/s"
    if unit == "rad":
        return f"{value:.3f} rad"
    if unit == "ms":
        return f"{value:.2f} ms"
    if unit == "s":
        return f"{value:.3f} s"
    if unit in ("ohm", "A", "MB"):
        return f"{value:.6g} {'Ω' if unit == 'ohm' else unit}"
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def rounded(value, key: str = ""):
    """A JSON-ready copy with numbers at the precision they deserve (see the module's note)."""
    if isinstance(value, dict):
        return {name: rounded(item, name) for name, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [rounded(item, key) for item in value]
    if isinstance(value, float) and math.isfinite(value) and value != 0.0:
        return float(f"{value:.7g}") if _unit(key) in ("K", "W") else float(f"{value:.6g}")
    return value
