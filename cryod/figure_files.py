"""What every figure cryod writes has in common: how it is saved and how long curves are thinned.

Examples
--------
>>> import numpy as np
>>> [len(part) for part in thin(np.arange(10000), np.arange(10000))]
[5000, 5000]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Most points drawn per curve.
MOST_POINTS = 4000


def save_figure(figure, path: Path) -> Path:
    """Lay out, write ``figure`` to ``path`` (PNG, 110 dpi), close it; returns ``path``."""
    import matplotlib.pyplot as plt

    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def thin(*arrays):
    """Every n-th point of each array, so the first has at most about :data:`MOST_POINTS`."""
    step = max(1, np.asarray(arrays[0]).size // MOST_POINTS)
    return [np.asarray(array)[::step] for array in arrays]
