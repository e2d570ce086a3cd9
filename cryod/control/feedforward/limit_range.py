"""The feedforward's limit with the model's uncertainty: the range the limit lies in for the model the lab has.

The limit (:func:`cryod.control.feedforward.limit.feedforward_limit`) depends on
the model: the mean heater power that holds the setpoint (the heater-to-T2 DC
gain), the heater's path at the line's harmonics (its time constants) and the
line it has to cancel (the line gain from T5 to T2). A model identified by
``cryod identify`` states how well it knows those parameters
(:class:`cryod.model.uncertainty.ModelUncertainty`); the limit is then
computed for models drawn from that distribution, and its spread reported:
the median, the central 95 % range and the standard deviation. A limit near
the heater's authority (authority close to 1) is where this matters: there a
small error in the DC gain moves the mean power, and the limit with it.

Examples
--------
>>> from cryod.model import load_model
>>> print(limit_range(load_model(), 5.0, 50.0, 0.1))       # no stated uncertainty
None
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cryod.control.feedforward.limit import FeedforwardLimitError, feedforward_limit
from cryod.model import CryostatModel

#: Models drawn for the range.
DEFAULT_DRAWS = 100


@dataclass(frozen=True)
class LimitRange:
    """The limit over models drawn from the stated uncertainty (K, the daemon's measure).

    Attributes
    ----------
    median_K, low_K, high_K, standard_deviation_K : float
        Median, 2.5 and 97.5 percentiles, standard deviation of ``ptc_periodic_limit_K``.
    authority_low, authority_high : float
        2.5 and 97.5 percentiles of the authority.
    mean_heater_power_low_W, mean_heater_power_high_W : float
    draws : int
        Models for which a limit exists (the setpoint within the heater's reach).
    out_of_reach : int
        Drawn models for which the setpoint is out of the heater's reach.
    """

    median_K: float
    low_K: float
    high_K: float
    standard_deviation_K: float
    authority_low: float
    authority_high: float
    mean_heater_power_low_W: float
    mean_heater_power_high_W: float
    draws: int
    out_of_reach: int

    def summary(self) -> dict:
        return {"median_K": self.median_K, "low_K": self.low_K, "high_K": self.high_K,
                "standard_deviation_K": self.standard_deviation_K, "authority_low": self.authority_low,
                "authority_high": self.authority_high, "mean_heater_power_low_W": self.mean_heater_power_low_W,
                "mean_heater_power_high_W": self.mean_heater_power_high_W, "draws": self.draws,
                "out_of_reach": self.out_of_reach, "coverage": "central 95 %"}

    def describe(self) -> str:
        """One line: the range in mK."""
        return (f"{self.low_K * 1e3:.4f} to {self.high_K * 1e3:.4f} mK (central 95 % of {self.draws} models drawn "
                f"from the model's stated uncertainty; median {self.median_K * 1e3:.4f} mK, standard deviation "
                f"{self.standard_deviation_K * 1e6:.2f} µK)"
                + (f"; for {self.out_of_reach} drawn models the setpoint is out of the heater's reach"
                   if self.out_of_reach else ""))


def limit_range(model: CryostatModel, setpoint_K: float, heater_resistance_ohm: float, max_current_A: float,
                period_s: float = 0.08, *, draws: int = DEFAULT_DRAWS, seed: int | None = 0,
                **options) -> LimitRange | None:
    """The limit's spread over models drawn from ``model.uncertainty``; None when the model states none.

    Parameters
    ----------
    model : CryostatModel
    setpoint_K, heater_resistance_ohm, max_current_A, period_s : float
        As for :func:`~cryod.control.feedforward.limit.feedforward_limit`.
    draws : int
        Models drawn.
    seed : int, optional
    **options
        More keyword arguments of ``feedforward_limit`` (``heater_delay_s``, ``measure``, ...).

    Returns
    -------
    LimitRange or None
    """
    if model.uncertainty is None:
        return None
    limits, authorities, powers = [], [], []
    out_of_reach = 0
    for drawn in model.uncertainty.sampled_models(model, draws, seed):
        try:
            limit = feedforward_limit(drawn, setpoint_K, heater_resistance_ohm, max_current_A, period_s,
                                      certify=False, **options)
        except FeedforwardLimitError:
            out_of_reach += 1
            continue
        limits.append(limit.ptc_periodic_limit_K)
        authorities.append(limit.authority)
        powers.append(limit.mean_heater_power_W)
    if not limits:
        return LimitRange(math.nan, math.nan, math.nan, math.nan, math.nan, math.nan, math.nan, math.nan, 0,
                          out_of_reach)
    limits_K = np.asarray(limits)
    low, median, high = np.percentile(limits_K, [2.5, 50.0, 97.5])
    return LimitRange(float(median), float(low), float(high), float(np.std(limits_K, ddof=1)) if limits_K.size > 1
                      else 0.0, float(np.percentile(authorities, 2.5)), float(np.percentile(authorities, 97.5)),
                      float(np.percentile(powers, 2.5)), float(np.percentile(powers, 97.5)), int(limits_K.size),
                      out_of_reach)


__all__ = ["LimitRange", "limit_range", "DEFAULT_DRAWS"]
