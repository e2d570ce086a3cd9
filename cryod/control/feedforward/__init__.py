"""The feedforward: a heater waveform locked to the cooler that cancels its line on the flange.

The term is :mod:`cryod.control.feedforward.term`; its names are also here, where the control
terms' table (:data:`cryod.control.terms.TERM_TYPES`) and users import them from.
"""

from cryod.control.feedforward.term import FeedforwardSettings, FeedforwardTerm, SynchronousEstimator

__all__ = ["FeedforwardSettings", "FeedforwardTerm", "SynchronousEstimator"]
