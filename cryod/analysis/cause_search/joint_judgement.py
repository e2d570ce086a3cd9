"""Judge a further cause jointly: on top of the causes named, on what it adds and at its own signature.

While the causes named on a path leave a discrepancy, every cause not yet
named is fitted on top of them (:func:`next_cause`); the leading ones, and
those that take most of what is left at their own signature, are refitted
jointly with the causes named (their numbers and the recalibration all free:
a first cause that took part of what the second explains gives it back) and
each is judged on what it adds in that joint fit: it counts (25 and 5 sigma)
and removes 70 % of everything left, or most of what is left at its own
signature (:func:`cryod.analysis.cause_search.rules.admits_further_cause`; the
bands of :mod:`cryod.analysis.cause_signature`). A fixed share of everything
left misfires when the first cause is close but not exact: what it leaves is
then large everywhere, and a second cause's share of it small however exactly
it explains its own part. Every candidate judged is kept
(:class:`~cryod.analysis.cause_search.results.FurtherCandidate`): what is left
is attributed to them (:mod:`cryod.analysis.cause_search.what_is_left`).
"""

from __future__ import annotations

from dataclasses import dataclass

from cryod.analysis.candidates import CandidateFit
from cryod.analysis.cause_search.at_signature import judged_at_signature
from cryod.analysis.cause_search.first_round import FirstRound
from cryod.analysis.cause_search.joint_refit import joint_fit, refit_jointly
from cryod.analysis.cause_search.results import CausePath, FurtherCandidate, JointFit
from cryod.analysis.cause_search.rules import (
    admits_further_cause,
    further_leading,
    leading_candidates,
    reshapes_a_named_cause,
)
from cryod.analysis.cause_signature import BandExcess, band_of, share_at_signature
from cryod.analysis.decision import CandidateScore, decide, score_candidate


@dataclass(frozen=True, kw_only=True)
class NextCause:
    """What the search found on top of a path's causes.

    Attributes
    ----------
    best : CandidateScore or None
        The candidate named next (refitted jointly); None when none is admitted.
    refined : dict of str to JointFit
        The joint fits the candidates were judged on.
    judged : tuple of FurtherCandidate
        Every candidate fitted on top, judged.
    refused : FurtherCandidate or None
        When none is admitted, the one that added most (what the reason names).
    """

    best: CandidateScore | None
    refined: dict[str, JointFit]
    judged: tuple[FurtherCandidate, ...] = ()
    refused: FurtherCandidate | None = None


def judged_candidate(cause: str, score: CandidateScore, before: dict[str, BandExcess], after: dict[str, BandExcess],
                     joint: bool, reshapes: bool = False) -> FurtherCandidate:
    """A candidate on top of the causes named, judged (:func:`~cryod.analysis.cause_search.rules.
    admits_further_cause`; only a joint fit can be admitted, and not one that only ``reshapes`` a cause named:
    :func:`~cryod.analysis.cause_search.rules.reshapes_a_named_cause`)."""
    band = band_of(cause)
    share = share_at_signature(cause, before, after)
    admitted = joint and not reshapes and admits_further_cause(score.counts, score.explained_fraction, share,
                                                               before[band])
    return FurtherCandidate(cause=cause, joint=joint, improvement=score.improvement, significance=score.significance,
                            explained_fraction=score.explained_fraction, band=band, before=before[band], share=share,
                            admitted=admitted, off_signature=score.off_signature, reshapes=reshapes)


def judge_on_path(first: FirstRound, path: CausePath, fits: dict[str, CandidateFit],
                  refined: dict[str, JointFit]) -> tuple[dict[str, CandidateScore], tuple[FurtherCandidate, ...]]:
    """Each candidate in ``fits`` scored against ``path``'s model (its joint fit where it has one), held to its own
    signature (:mod:`cryod.analysis.cause_search.at_signature`) and judged."""
    context, bands = path.context, first.bands
    before = bands.bands(context.base_replay)
    scores, judged = {}, []
    for cause, fit in fits.items():
        joint = refined.get(cause)
        replay = joint.fit.replay if joint is not None else fit.replay
        scores[cause] = judged_at_signature(bands, context.base_replay, score_candidate(
            context, joint.fit if joint is not None else fit, path.remaining), replay)
        reshapes = reshapes_a_named_cause(cause, path.cause_names(),
                                          scores[cause].improvement / max(first.recalibrated.excess, 1e-300))
        judged.append(judged_candidate(cause, scores[cause], before, bands.bands(replay), joint is not None,
                                       reshapes))
    return scores, tuple(judged)


def next_cause(first: FirstRound, path: CausePath, untried: tuple[str, ...]) -> NextCause:
    """Every untried cause not yet in the path's model fitted on top of its causes and judged jointly (see the
    module doc). The leading candidates are chosen among as before (the rules of :mod:`cryod.analysis.decision`,
    ties included); when that choice is not admitted, the admitted candidate that adds most is named."""
    search = first.search
    fits = search.fit_candidates(path.context, [cause for cause in untried
                                                if cause not in path.context.base_model.effect_names()],
                                 " (next cause)")
    first_scores, first_judged = judge_on_path(first, path, fits, {})
    if not any(score.counts for score in first_scores.values()):
        return NextCause(best=None, refined={}, judged=first_judged)
    shares = {item.cause: item.share for item in first_judged}
    leading = leading_candidates(first_scores)
    choice = refit_jointly(search, path, fits, first_scores, first.bands, leading)
    refined = dict(choice.refined)
    for cause in further_leading(first_scores, shares):
        if cause not in refined:
            refined[cause] = joint_fit(search, path.recalibration, fits[cause], path.named_effects)
    scores, judged = judge_on_path(first, path, fits, refined)
    admitted = {item.cause for item in judged if item.admitted}
    best = choice.decision.best
    if best is None or best.cause not in admitted:
        best = _best_admitted(path, scores, refined, admitted)
    if best is None:
        joint = [item for item in judged if item.joint]
        refused = max(joint, key=lambda item: item.improvement) if joint else None
        return NextCause(best=None, refined=refined, judged=judged, refused=refused)
    return NextCause(best=scores[best.cause], refined=refined, judged=judged)


def _best_admitted(path: CausePath, scores: dict[str, CandidateScore], refined: dict[str, JointFit],
                   admitted: set[str]) -> CandidateScore | None:
    """Of the admitted candidates, the one the rules of :mod:`cryod.analysis.decision` choose (the largest
    improvement; a tie to the fewer parameters)."""
    if not admitted:
        return None
    context = path.context
    fits = {cause: refined[cause].fit for cause in admitted}
    decision = decide(path.remaining, [scores[cause] for cause in admitted],
                      lambda a, b: context.distinctness(fits[a].replay, fits[b].replay),
                      {cause: fit.parameter_count for cause, fit in fits.items()})
    return decision.best


__all__ = ["NextCause", "judge_on_path", "judged_candidate", "next_cause"]
