"""What binds the feedforward's limit, in the lab's words: the heater's 0 W floor, its top, or neither.

The limit (:mod:`cryod.control.feedforward.limit`) is the least cooler-synchronous T2
any heater waveform can leave, with the waveform's mean fixed by the setpoint and its
values within 0 .. R I_max^2. What the best waveform rests on says what would change it:

* **the 0 W floor**: the setpoint needs too little mean power for the swing that would
  cancel the line. A bigger heater does not help (its top is not reached); a higher
  setpoint does (more mean power, more room below it).
* **the top** R I_max^2: the setpoint needs so much mean power that the swing hits the
  heater's top. A bigger heater helps (the figure says by how much), as does a lower setpoint.
* **neither**: the heater can cancel the line; what is left is the noise of the line's
  estimate, which a longer averaging lowers.

A value measured against the limit is compared in the same measure (harmonics 1-6 of T2,
sqrt(2) x rms); one below the limit is said, with why (:func:`measured_against_limit`).

Examples
--------
>>> from cryod.model import load_model
>>> from cryod.control.feedforward.limit import feedforward_limit, limit_changes
>>> model = load_model()
>>> limit = feedforward_limit(model, 5.0, 50.0, 0.1, certify=False)
>>> binding = limit_binding(limit, limit_changes(model, 5.0, 0.5))
>>> binding.bound, round(binding.floor_fraction, 2)
('floor', 0.45)
>>> print(binding.explanation)                              # doctest: +NORMALIZE_WHITESPACE
the heater's 0 W floor binds: the setpoint needs 112.9 mW on average, and the best waveform rests at 0 W for 45 %
of each cooler cycle (cancelling the line's fundamental would take 235.0 mW each way). A bigger heater does not
help (R I_max^2 x 2 (1000 mW): 526.0 µK); a higher setpoint does (setpoint 5.5 K: 116.5 µK).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cryod.control.feedforward.limit import FeedforwardLimit, LimitChange

#: A waveform within this fraction of R I_max^2 of a bound rests on it.
AT_BOUND = 1e-3
#: A bound the waveform touches binds when removing it (a heater twice as large, for the top) would lower the
#: limit by more than this fraction.
MATTERS = 0.01
#: The words of each bound.
FLOOR, TOP, BOTH, NONE = "floor", "top", "floor and top", "none"


@dataclass(frozen=True)
class LimitBinding:
    """What binds the limit.

    Attributes
    ----------
    bound : str
        ``floor`` (0 W), ``top`` (R I_max^2), ``floor and top``, or ``none`` (the estimate's noise is what is left).
    floor_fraction, top_fraction : float
        Fractions of the cooler's cycle the best waveform rests at 0 W and at R I_max^2.
    explanation : str
        What binds and what would change it, with the figures.
    """

    bound: str
    floor_fraction: float
    top_fraction: float
    explanation: str

    def summary(self) -> dict:
        """For ``--json``."""
        return {"bound": self.bound, "floor_fraction": self.floor_fraction, "top_fraction": self.top_fraction,
                "explanation": self.explanation}


def _microkelvin(value_K: float) -> str:
    return f"{value_K * 1e6:.1f} µK"


def _milliwatt(value_W: float) -> str:
    return f"{value_W * 1e3:.1f} mW"


def _said(change: LimitChange | None) -> str:
    """``change: figure`` (or why there is none)."""
    if change is None:
        return ""
    limit = change.point.limit
    return f"{change.change}: " + ("out of the heater's reach" if limit is None else _microkelvin(
        limit.ptc_periodic_limit_K))


def _advice(first: str, first_figure: str, second: str, second_figure: str) -> str:
    """``First (its figure); second (its figure).``, each figure where there is one."""
    return (first + (f" ({first_figure})" if first_figure else "") + "; " + second
            + (f" ({second_figure})." if second_figure else "."))


def _changes_by_kind(limit: FeedforwardLimit, changes) -> dict[str, LimitChange]:
    """The changes of :func:`~cryod.control.feedforward.limit.limit_changes` by what they change: ``bigger heater``,
    ``higher setpoint``, ``lower setpoint``."""
    kinds = {}
    for change in changes:
        point = change.point
        if point.max_heater_power_W > limit.max_heater_power_W * (1 + 1e-9):
            kinds["bigger heater"] = change
        elif point.mean_heater_power_W > limit.mean_heater_power_W:
            kinds["higher setpoint"] = change
        elif point.mean_heater_power_W < limit.mean_heater_power_W:
            kinds["lower setpoint"] = change
    return kinds


def limit_binding(limit: FeedforwardLimit, changes=()) -> LimitBinding:
    """What binds ``limit``, from where its best waveform rests, said with the figures of ``changes``.

    Parameters
    ----------
    limit : FeedforwardLimit
    changes : iterable of LimitChange
        What would change it (:func:`~cryod.control.feedforward.limit.limit_changes`, or the learned
        plant's): the figures of a bigger heater and another setpoint are quoted from them. A top the
        waveform touches while it also rests at 0 W binds only when the bigger heater's limit is lower.

    Returns
    -------
    LimitBinding
    """
    waveform = np.asarray(limit.waveform_power_W, dtype=float)
    top = limit.max_heater_power_W
    floor_fraction = float(np.mean(waveform <= AT_BOUND * top)) if waveform.size else 0.0
    top_fraction = float(np.mean(waveform >= (1.0 - AT_BOUND) * top)) if waveform.size else 0.0
    kinds = _changes_by_kind(limit, changes)
    bigger, higher, lower = (_said(kinds.get(kind))
                             for kind in ("bigger heater", "higher setpoint", "lower setpoint"))
    at_floor = limit.authority_limited and floor_fraction > 0.0
    at_top = limit.authority_limited and top_fraction > 0.0
    doubled = kinds["bigger heater"].point.limit if "bigger heater" in kinds else None
    if at_top and at_floor and doubled is not None and \
            doubled.ptc_periodic_limit_K >= (1.0 - MATTERS) * limit.ptc_periodic_limit_K:
        at_top = False                      # touched, but a bigger heater changes nothing: the floor binds
    mean = _milliwatt(limit.mean_heater_power_W)
    if at_floor and at_top:
        bound = BOTH
        text = (f"both of the heater's bounds bind: the best waveform rests at 0 W for {100 * floor_fraction:.0f} % "
                f"and at its top R I_max^2 = {_milliwatt(top)} for {100 * top_fraction:.0f} % of each cooler cycle, "
                f"around the {mean} the setpoint needs. A bigger heater helps" + (f" ({bigger})." if bigger else "."))
    elif at_floor:
        bound = FLOOR
        text = (f"the heater's 0 W floor binds: the setpoint needs {mean} on average, and the best waveform rests "
                f"at 0 W for {100 * floor_fraction:.0f} % of each cooler cycle (cancelling the line's fundamental "
                f"would take {_milliwatt(limit.line_power_needed_W)} each way). "
                + _advice("A bigger heater does not help", bigger, "a higher setpoint does", higher))
    elif at_top:
        bound = TOP
        text = (f"the heater's top R I_max^2 = {_milliwatt(top)} binds: the setpoint needs {mean} on average, "
                f"{_milliwatt(top - limit.mean_heater_power_W)} below the top, and the best waveform rests at the "
                f"top for {100 * top_fraction:.0f} % of each cooler cycle. "
                + _advice("A bigger heater helps", bigger, "so does a lower setpoint", lower))
    else:
        bound = NONE
        text = (f"no bound binds: the heater can cancel the line (it can put "
                f"{_milliwatt(limit.largest_line_power_W)} at the line, {_milliwatt(limit.line_power_needed_W)} are "
                f"needed); what is left is the noise of "
                f"the line's estimate, {_microkelvin(limit.noise_floor_K)} over {limit.averaging_time_s:g} s of "
                f"readings, which a longer averaging lowers.")
    return LimitBinding(bound, floor_fraction, top_fraction, text)


def measured_against_limit(measured_K: float, limit_K: float, noise_K: float, source: str = "the model") -> str:
    """A measured synchronous T2 against the limit, both harmonics 1-6: one below the limit is said, with why.

    Parameters
    ----------
    measured_K : float
        T2's part synchronous with the cooler, harmonics 1-6 (K, sqrt(2) x rms).
    limit_K : float
        The limit in the same measure (K).
    noise_K : float
        The noise of the measured value's estimate (K, same measure).
    source : str
        Where the limit's inputs come from (``the model``, ``the learned plant``), for the explanation.

    Examples
    --------
    >>> print(measured_against_limit(253.6e-6, 345.3e-6, 3.6e-6))     # doctest: +NORMALIZE_WHITESPACE
    measured 253.6 µK is below the limit 345.3 µK (harmonics 1-6 both) by 91.7 µK, more than the estimate's noise
    (3.6 µK): the limit rests on the model's line, plant and mean heater power, and this cryostat differs from them
    >>> print(measured_against_limit(540e-6, 526e-6, 3.6e-6))
    measured 540.0 µK, 1.03 x the limit 526.0 µK (harmonics 1-6 both)
    """
    if not (math.isfinite(measured_K) and math.isfinite(limit_K)):
        return "measured against the limit: not known yet"
    if measured_K >= limit_K:
        ratio = f", {measured_K / limit_K:.2f} x the limit" if limit_K > 0.0 else ", above the limit"
        return f"measured {_microkelvin(measured_K)}{ratio} {_microkelvin(limit_K)} (harmonics 1-6 both)"
    below = limit_K - measured_K
    start = (f"measured {_microkelvin(measured_K)} is below the limit {_microkelvin(limit_K)} (harmonics 1-6 both) by "
             f"{_microkelvin(below)}")
    if below <= 2.0 * noise_K:
        return f"{start}, within twice the estimate's noise ({_microkelvin(noise_K)}): no measured value can say more"
    owner = source.removeprefix("the ")
    return (f"{start}, more than the estimate's noise ({_microkelvin(noise_K)}): the limit rests on the {owner}'s "
            f"line, plant and mean heater power, and this cryostat differs from them")


__all__ = ["LimitBinding", "limit_binding", "measured_against_limit", "FLOOR", "TOP", "BOTH", "NONE"]
