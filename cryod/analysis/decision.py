"""Naming the cause: each candidate judged on the held-out blocks, against the measured noise.

All sums below are over the held-out samples of both thermometers, each
residual divided by its measured noise rms (so pure noise gives 1 per term),
with ``n`` terms in all:

* ``W_base``, ``W_c``: the base model's and candidate c's sums of squares.
* improvement ``Delta_c = W_base - W_c``.
* distinctness ``D_c``: the sum of squares of the difference between the two
  predictions. If the base model were right, the held-out noise is independent
  of the fit, so ``Delta_c`` would be normal with mean ``-D_c`` and standard
  deviation ``2 sqrt(D_c)``; the candidate's significance is
  ``Delta_c / (2 sqrt(D_c))`` standard deviations.
* the base model's excess ``E = W_base - n``, significance ``E / sqrt(2 n)``.

The rules:

1. The record shows a discrepancy when ``E`` is above 6 standard deviations
   *and* above 5 % of ``n`` (a misfit whose power is at least 5 % of the
   noise's; below that the model agrees within the noise in any practical
   sense). No discrepancy: the cause is ``none``, whatever a candidate does.
2. A candidate counts when its significance is at least 5 and its
   improvement at least 25, and its fit is not at a physical limit of its
   effect (the cold end's drift reaching the flange more than fully: the
   record then asks for more than the cause can be). The one with the largest improvement is the best.
3. With a discrepancy, the best candidate is named if it explains at least
   70 % of the excess (``Delta / E``), or leaves no discrepancy by rule 1.
   Otherwise, or when no candidate counts, the cause is ``unexplained``.
4. When another counting candidate is worse than the best by less than 1.5
   standard deviations of the difference between their two predictions
   (``2 sqrt(D_ab)``), the record cannot tell them apart: one whose fit needs
   the recalibration to move a parameter by more than half its tolerance (the
   spread expected of a base model's parameters) comes last; then the one with
   fewer parameters is named (at equal numbers, the earlier in
   :data:`TIE_PREFERENCE`), and the reason says so. A record with only the PTC
   line cannot tell a lagging flange thermometer from a link of unit gain
   (one parameter against two: ``sensor_lag``), nor a pair of thermometers
   lagging differently from a link (two against two: ``link_dynamics``).

The gain of a model is the rms of the noise-normalised held-out residuals,
``sqrt(W / n)``; the ratio is base over extended.

Examples
--------
>>> significance(improvement=400.0, distinctness=400.0)
10.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cryod.analysis.candidates import CandidateFit, FitContext

DISCREPANCY_SIGMA = 6.0
DISCREPANCY_FRACTION_OF_NOISE = 0.05
CANDIDATE_SIGMA = 5.0
CANDIDATE_MINIMUM_IMPROVEMENT = 25.0
EXPLAINED_FRACTION = 0.7
TIE_SIGMA = 1.5
GAIN_METRIC = ("held-out rms of the T2 and T5 residuals, each divided by its measured noise rms "
               "(1.0 = noise only)")


def significance(improvement: float, distinctness: float) -> float:
    """Improvement in standard deviations of its null distribution (0 if the predictions coincide)."""
    if distinctness <= 0.0:
        return 0.0
    return improvement / (2.0 * math.sqrt(distinctness))


@dataclass(frozen=True)
class Gain:
    """Held-out residual of the base and the extended model (see :data:`GAIN_METRIC`)."""

    metric: str
    base: float
    extended: float
    ratio: float

    def as_dict(self) -> dict:
        return {"metric": self.metric, "base": self.base, "extended": self.extended, "ratio": self.ratio}


@dataclass(frozen=True)
class CandidateScore:
    """How one candidate does on the held-out blocks.

    Attributes
    ----------
    cause : str
    held_out_flange, held_out_stage : float
        Held-out sums of squares of T2 and T5 in noise units.
    improvement : float
        Delta against the base model (noise-variance units).
    distinctness : float
        D: how much its prediction differs from the base model's.
    significance : float
        Delta / (2 sqrt(D)).
    explained_fraction : float
        Delta / E (0 when the base model shows no excess).
    gain : Gain
    """

    cause: str
    held_out_flange: float
    held_out_stage: float
    improvement: float
    distinctness: float
    significance: float
    explained_fraction: float
    gain: Gain
    #: Its fit sits at a physical limit of the effect: the record asks for more than the cause can be.
    at_limit: bool = False
    #: What it removes lies mostly outside its own signature: it stands for another cause
    #: (:func:`cryod.analysis.cause_search.rules.shows_at_its_signature`).
    off_signature: bool = False

    @property
    def counts(self) -> bool:
        return (self.significance >= CANDIDATE_SIGMA and self.improvement >= CANDIDATE_MINIMUM_IMPROVEMENT
                and not self.at_limit and not self.off_signature)


@dataclass(frozen=True)
class BaseDiscrepancy:
    """The base model's held-out misfit beyond noise."""

    terms: int
    sum_of_squares: float
    excess: float
    significance: float

    @property
    def present(self) -> bool:
        return (self.significance >= DISCREPANCY_SIGMA
                and self.excess >= DISCREPANCY_FRACTION_OF_NOISE * self.terms)


@dataclass(frozen=True)
class Decision:
    """The named cause and why."""

    cause: str
    reason: str
    best: CandidateScore | None
    base: BaseDiscrepancy
    gain: Gain
    #: Causes the record cannot tell from the one named (rule 4).
    tied: tuple = ()


def base_discrepancy(context: FitContext) -> BaseDiscrepancy:
    mask = context.held_out_mask
    flange, stage = context.chi_square(context.base_replay, mask)
    terms = 2 * int(np.count_nonzero(mask))
    total = flange + stage
    excess = total - terms
    return BaseDiscrepancy(terms, total, excess, excess / math.sqrt(2.0 * terms))


def score_candidate(context: FitContext, fit: CandidateFit, base: BaseDiscrepancy) -> CandidateScore:
    """Held-out comparison of one candidate with the base model."""
    mask = context.held_out_mask
    flange, stage = context.chi_square(fit.replay, mask)
    improvement = base.sum_of_squares - (flange + stage)
    distinctness = context.distinctness(fit.replay, context.base_replay)
    explained = improvement / base.excess if base.excess > 0.0 else 0.0
    gain = gain_between(base.sum_of_squares, flange + stage, base.terms)
    return CandidateScore(fit.cause, flange, stage, improvement, distinctness,
                          significance(improvement, distinctness), explained, gain, fit.at_limit)


def gain_between(base_sum_of_squares: float, extended_sum_of_squares: float, terms: int) -> Gain:
    base_rms = math.sqrt(base_sum_of_squares / terms)
    extended_rms = math.sqrt(extended_sum_of_squares / terms)
    return Gain(GAIN_METRIC, base_rms, extended_rms, base_rms / extended_rms if extended_rms > 0 else math.inf)


#: At equal numbers of parameters, a tie goes to the cause earlier in this list: a link that differs
#: is more common than two thermometers lagging differently, and so on.
TIE_PREFERENCE = ("link_dynamics", "sensor_lag", "dead_time", "heater_nonlinearity", "heat_capacity_temperature",
                  "ptc_harmonics", "ptc_frequency_drift", "ptc_amplitude_modulation", "ptc_stage_drift")


def _preference(cause: str) -> int:
    return TIE_PREFERENCE.index(cause) if cause in TIE_PREFERENCE else len(TIE_PREFERENCE)


def _tied_with(best: CandidateScore, counting: list[CandidateScore], distinctness) -> list[CandidateScore]:
    """Candidates the held-out data cannot tell from the best: worse by less than 1.5 standard deviations."""
    tied = []
    for score in counting:
        if score is best:
            continue
        spread = 2.0 * math.sqrt(max(distinctness(score.cause, best.cause), 0.0))
        if best.improvement - score.improvement <= TIE_SIGMA * spread + 1.0:
            tied.append(score)
    return tied


def decide(base: BaseDiscrepancy, scores: list[CandidateScore], distinctness=None,
           parameter_counts: dict | None = None, strained: dict | None = None) -> Decision:
    """Apply the rules of this module.

    Parameters
    ----------
    base : BaseDiscrepancy
    scores : list of CandidateScore
    distinctness : callable, optional
        ``distinctness(cause_a, cause_b)``: held-out sum of squares of the
        difference between two candidates' predictions (noise units); with it,
        candidates the data cannot tell apart from the best are a tie.
    parameter_counts : dict, optional
        Number of fitted parameters per cause; a tie goes to the fewest.
    strained : dict, optional
        Per cause, whether its fit needed the recalibration to move a parameter
        by more than half its tolerance (beyond the spread expected of a base
        model's parameters): in a tie such a cause comes after the others.
    """
    unchanged = gain_between(base.sum_of_squares, base.sum_of_squares, base.terms)
    counting = [score for score in scores if score.counts]
    best = max(counting, key=lambda score: score.improvement) if counting else None
    tie_text = ""
    tied_causes: tuple[str, ...] = ()
    if best is not None and distinctness is not None:
        tied = _tied_with(best, counting, distinctness)
        if tied:
            counts, strain = parameter_counts or {}, strained or {}
            simplest = min([best] + tied, key=lambda score: (strain.get(score.cause, False), counts.get(score.cause, 1),
                                                             _preference(score.cause)))
            others = ", ".join(score.cause for score in [best] + tied if score is not simplest)
            why = ("the others need the recalibration beyond the spread expected of a base model's parameters"
                   if any(strain.get(score.cause, False) for score in [best] + tied if score is not simplest)
                   and not strain.get(simplest.cause, False)
                   else "with the fewest parameters or, at equal numbers, the more common cause")
            tie_text = (f"; this record cannot tell {simplest.cause} from {others} (within {TIE_SIGMA:g} standard "
                        f"deviations on the held-out data): {simplest.cause} is named, {why}")
            tied_causes = tuple(score.cause for score in [best] + tied if score is not simplest)
            best = simplest
    excess_text = (f"the base model's held-out excess is {base.excess:.4g} "
                   f"({base.significance:.1f} sigma, {100.0 * base.excess / base.terms:.2f} % of the noise power)")
    if not base.present:
        reason = f"no discrepancy beyond the noise: {excess_text}"
        if best is not None:
            reason += f"; {best.cause} would improve it by {best.improvement:.4g} ({best.significance:.1f} sigma), too little to matter"
        return Decision("none", reason, None, base, unchanged)
    if best is None:
        return Decision("unexplained", f"{excess_text}, and no candidate improves it significantly", None, base,
                        unchanged)
    remaining = base.excess - best.improvement
    remaining_significance = remaining / math.sqrt(2.0 * base.terms)
    leaves_nothing = not (remaining_significance >= DISCREPANCY_SIGMA
                          and remaining >= DISCREPANCY_FRACTION_OF_NOISE * base.terms)
    if best.explained_fraction >= EXPLAINED_FRACTION or leaves_nothing:
        reason = (f"{excess_text}; {best.cause} removes {100.0 * best.explained_fraction:.1f} % of it "
                  f"({best.significance:.1f} sigma)" + (tie_text or ", the most of any candidate"))
        return Decision(best.cause, reason, best, base, best.gain, tied_causes)
    reason = (f"{excess_text}; the best candidate, {best.cause}, removes only "
              f"{100.0 * best.explained_fraction:.1f} % of it and leaves a discrepancy of "
              f"{remaining_significance:.1f} sigma")
    return Decision("unexplained", reason, best, base, unchanged)
