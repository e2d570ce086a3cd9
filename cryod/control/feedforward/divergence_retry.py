"""After a divergence: why it was, how many there were, and when learning starts again.

Why, and how well it works: docs/explanation/feedforward.md ("Never worse").

When the divergence guard (:mod:`cryod.control.feedforward.divergence_guard`) trips, the
feedforward's waveform fades out (its ``diverged`` state,
:mod:`cryod.control.feedforward.state_machine`) with the guard's reason kept for the status; once
the waveform is out, the learned plant goes back to the model's and learning waits before it starts
again: ``retry_after_s`` after the first divergence, doubled for each one since the start, never
more than :data:`LONGEST_RETRY_S`.

Examples
--------
>>> retry = DivergenceRetry()
>>> retry.tripped("T2's synchronous part grew at every one of 5 learning steps", retry_after_s=120.0)
120.0
>>> retry.faded_out(1000.0, retry_after_s=120.0)
>>> retry.pending(1119.0), retry.pending(1120.0), retry.reason
(True, False, None)
>>> retry.tripped("again", retry_after_s=120.0), retry.count
(240.0, 2)
"""

from __future__ import annotations

import math

#: The wait before learning again after a divergence doubles with each one, up to this (s).
LONGEST_RETRY_S = 3600.0


class DivergenceRetry:
    """The divergences since the start, the one fading out, and when learning may start again (module notes)."""

    def __init__(self):
        #: Why the waveform is fading out after a divergence (None: it is not).
        self.reason: str | None = None
        #: Divergences since the start.
        self.count = 0
        #: No learning before this (s, on the loop's clock).
        self.learn_again_s = -math.inf

    def wait_s(self, retry_after_s: float) -> float:
        """The wait after the latest divergence (s): ``retry_after_s`` doubled for each one before it."""
        return min(retry_after_s * 2.0 ** (self.count - 1), LONGEST_RETRY_S)

    def tripped(self, reason: str, retry_after_s: float) -> float:
        """The guard tripped for ``reason``: counted, kept while the waveform fades out; the wait that follows (s)."""
        self.reason = reason
        self.count += 1
        return self.wait_s(retry_after_s)

    def faded_out(self, time_s: float, retry_after_s: float) -> None:
        """The waveform is out after the divergence at ``time_s`` (s): learning waits from now."""
        self.learn_again_s = time_s + self.wait_s(retry_after_s)
        self.reason = None

    def pending(self, time_s: float) -> bool:
        """Whether learning still waits at ``time_s`` (s) after a divergence."""
        return time_s < self.learn_again_s


__all__ = ["DivergenceRetry", "LONGEST_RETRY_S"]
