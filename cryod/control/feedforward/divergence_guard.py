"""The divergence guard: a learning that makes T2 worse is caught, and the feedforward steps back.

Why, and how well it works: docs/explanation/feedforward.md ("Never worse").

The learning converges when the plant it uses is close enough to the
cryostat's (within 90 degrees, and not too strong); a plant that changes faster
than it is learned, or a learned value that is wrong, makes each step move the
line the wrong way. After every learning step the guard is shown T2's
synchronous part as estimated with the waveform (without the probe) and the
line PI alone would leave (the line estimated while no waveform played, scaled
to the cooler's amplitude in T5 now). It trips when

* that residual has stayed above PI alone's (times :data:`ABOVE_FACTOR`) for
  ``intervals`` learning steps in a row, or
* it has grown at every one of ``intervals`` steps in a row, each time by
  :data:`STEP_GROWTH` at least and by :data:`GROWTH_FACTOR` in all, to above
  :data:`GROWTH_FLOOR` of PI alone's (below that, noise alone can look like
  growth; a residual that rises once, when the heater's room shrinks, and stays
  is not a divergence).

What the feedforward then does (fade the waveform out, reset the learned plant
to the model, say why, try again later) is up to it.

Examples
--------
>>> guard = DivergenceGuard(intervals=3)
>>> [guard.observe(residual, 1.0e-3) for residual in (0.3e-3, 0.2e-3, 0.1e-3, 0.5e-3, 0.9e-3)]
[None, None, None, None, None]
>>> print(guard.observe(1.5e-3, 1.0e-3))
T2's synchronous part grew at every one of 3 learning steps, from 0.100 to 1.500 mK (PI alone: 1.000 mK)
"""

from __future__ import annotations

import collections

#: A residual above PI alone's times this counts as worse than PI alone.
ABOVE_FACTOR = 1.2
#: Growth over the steps that counts as diverging, at each step and in all ...
STEP_GROWTH = 1.05
GROWTH_FACTOR = 2.0
#: ... once the residual is above this fraction of PI alone's.
GROWTH_FLOOR = 0.1


class DivergenceGuard:
    """Watches T2's synchronous residual step after step (module notes).

    Parameters
    ----------
    intervals : int
        Learning steps in a row that make a divergence.
    """

    def __init__(self, intervals: int = 5):
        self.intervals = intervals
        self._residuals: collections.deque[float] = collections.deque(maxlen=intervals + 1)
        self._above = 0

    def clear(self) -> None:
        """Forget the steps seen (after a reset, or while no waveform plays)."""
        self._residuals.clear()
        self._above = 0

    def observe(self, residual_K: float, pi_alone_K: float) -> str | None:
        """One learning step's residual and PI alone's line (K); the reason when this makes a divergence."""
        self._residuals.append(residual_K)
        self._above = self._above + 1 if residual_K > ABOVE_FACTOR * pi_alone_K else 0
        if self._above >= self.intervals:
            return (f"T2's synchronous part has been above PI alone's for {self.intervals} learning steps "
                    f"({1e3 * residual_K:.3f} mK against {1e3 * pi_alone_K:.3f} mK)")
        values = list(self._residuals)
        if len(values) > self.intervals and all(b > STEP_GROWTH * a for a, b in zip(values, values[1:])) \
                and values[-1] >= GROWTH_FACTOR * values[0] and values[-1] > GROWTH_FLOOR * pi_alone_K:
            return (f"T2's synchronous part grew at every one of {self.intervals} learning steps, from "
                    f"{1e3 * values[0]:.3f} to {1e3 * values[-1]:.3f} mK (PI alone: {1e3 * pi_alone_K:.3f} mK)")
        return None


__all__ = ["ABOVE_FACTOR", "DivergenceGuard", "GROWTH_FACTOR", "GROWTH_FLOOR", "STEP_GROWTH"]
