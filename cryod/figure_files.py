"""What every figure cryod writes has in common: how it is saved, how long curves are thinned,
how the cooler's harmonics are marked on a spectrum.

Examples
--------
>>> import numpy as np
>>> [len(part) for part in thin(np.arange(10000), np.arange(10000))]
[5000, 5000]
>>> round(folded_frequency(2 * 1.72, 12.5), 2), round(folded_frequency(4 * 1.72, 12.5), 2)   # 4f is above 6.25 Hz
(3.44, 5.62)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Most points drawn per curve.
MOST_POINTS = 4000
#: Harmonics of the cooler marked on a spectrum.
HARMONICS = 6
#: Resolution of every figure written (dots per inch).
DPI = 110
#: zlib level of the PNG files: 1 writes a plot's large plain areas some times faster than the default 6, for
#: files about a tenth larger.
PNG_COMPRESS_LEVEL = 1


def save_figure(figure, path: Path) -> Path:
    """Lay out, write ``figure`` to ``path`` (PNG, :data:`DPI`), close it; returns ``path``.

    The figure is laid out at the resolution it is written at, so that the text measured for the layout is
    measured once (matplotlib keeps it per renderer), and the PNG is compressed at
    :data:`PNG_COMPRESS_LEVEL`."""
    import matplotlib.pyplot as plt

    figure.set_dpi(DPI)
    figure.tight_layout()
    figure.savefig(path, dpi=DPI, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    plt.close(figure)
    return path


def thin(*arrays):
    """Every n-th point of each array, so the first has at most about :data:`MOST_POINTS`."""
    step = max(1, np.asarray(arrays[0]).size // MOST_POINTS)
    return [np.asarray(array)[::step] for array in arrays]


def folded_frequency(frequency_hz: float, sample_hz: float) -> float:
    """Where a line at ``frequency_hz`` appears in the spectrum of data sampled at ``sample_hz`` (Hz)."""
    nyquist = sample_hz / 2.0
    return abs(((frequency_hz + nyquist) % sample_hz) - nyquist)


def mark_cooler_harmonics(axis, cooler_hz: float, sample_hz: float, harmonics: int = HARMONICS) -> None:
    """Dashed, labelled lines at the cooler's harmonics on a spectrum axis; those above the Nyquist
    frequency where sampling folds them, labelled with the frequency they come from."""
    for order in range(1, harmonics + 1):
        true_hz = order * cooler_hz
        aliased = true_hz > sample_hz / 2.0
        folded = folded_frequency(true_hz, sample_hz)
        axis.axvline(folded, color="tab:purple" if aliased else "tab:red", lw=0.6, ls="--", alpha=0.6)
        axis.annotate(f"{order}f" + (f" (aliased from {true_hz:.2f} Hz)" if aliased else ""),
                      (folded, 0.97), xycoords=("data", "axes fraction"), rotation=90, fontsize=7,
                      va="top", ha="right")
