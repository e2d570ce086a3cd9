"""Follow a path: name a first cause, then causes on top of it while one is needed.

From a first choice (a candidate refitted jointly with the recalibration), a
path names that cause and then, while the model with the causes named still
shows a discrepancy, fits every cause not yet named on top of them, refits the
leading ones jointly with the causes named (all their numbers and the
recalibration free) and judges each on what it adds and on its share of what
is left at its own signature
(:mod:`cryod.analysis.cause_search.joint_judgement`). Each time
a cause is named, the causes named before it are refitted with it (one that
took part of what it explains gives it back), and an earlier cause it made
unnecessary is left out (:mod:`cryod.analysis.cause_search.unneeded_causes`).
A further cause that leaves a discrepancy must also add to the generic
extension on the model without it
(:func:`cryod.analysis.cause_search.generic_judgement.further_cause_comparison`).
"""

from __future__ import annotations

import dataclasses

from cryod.analysis.cause_search.bounds import examine_bounds
from cryod.analysis.cause_search.first_round import FirstRound
from cryod.analysis.cause_search.generic_judgement import further_cause_comparison
from cryod.analysis.cause_search.joint_judgement import next_cause
from cryod.analysis.cause_search.joint_refit import refitted_causes, settled, starting_path
from cryod.analysis.cause_search.results import CausePath, FurtherCandidate, JointFit, NamedCause
from cryod.analysis.cause_search.rules import weighed_as_further_cause
from cryod.analysis.cause_search.unneeded_causes import without_unneeded
from cryod.analysis.decision import CandidateScore, gain_between


def follow_path(first: FirstRound, choice: CandidateScore, refined: dict[str, JointFit], most: int,
                causes: tuple[str, ...] | None = None) -> CausePath:
    """Name ``choice`` (the score of a candidate refitted jointly, whose joint fit is in ``refined``) first, then
    causes on top of it while one counts and removes at least 70 % of what is left, ``most`` causes in all.

    Every cause of the search (``causes``: those tried instead) is tried on top of those named, also one that made
    the first round worse: with a much larger effect unnamed, a small one's fit takes that effect's misfit (a
    thermometer's lag of 60 ms beside a heat capacity that removes 99.8 %), and only once the larger one is named
    does it fit what it stands for. A further cause that leaves a discrepancy, or was admitted on its share at its
    own signature alone (:func:`~cryod.analysis.cause_search.rules.weighed_as_further_cause`), and adds less than a
    cause must to the generic extension on the model without it is not named, and the path stops before it.
    """
    search = first.search
    path = starting_path(first)
    untried = tuple(search.scope.causes if causes is None else causes)
    untried += () if choice.cause in untried else (choice.cause,)
    best = choice
    for round_index in range(most):
        if round_index > 0:
            found = next_cause(first, path, untried)
            if found.best is None:
                return _stopped_before(path, found.refused, found.judged)
            best, refined = found.best, found.refined
        if not best.counts:
            break
        named = cause_named(first, path, best, refined[best.cause])
        if round_index == 0:
            examined, evidence = examine_bounds(first, named)
            named = dataclasses.replace(examined, at_bound=evidence)
        untried = tuple(cause for cause in untried if cause != best.cause)
        if round_index > 0 and weighed_as_further_cause(best.explained_fraction, named.remaining):
            comparison = further_cause_comparison(first, path, named, best.cause)
            if not comparison.causes_add:
                return dataclasses.replace(path, reasons=path.reasons + (
                    f"{best.cause} would remove {100.0 * best.explained_fraction:.1f} % of what is left but adds only "
                    f"{comparison.added:.4g} ({comparison.significance:.1f} sigma) to the generic extension: not a "
                    "further cause",), further=_refused(found.judged, best.cause))
        path = named
        if not path.remaining.present or len(path.causes) == most:
            break
    return path


def _refused(judged: tuple[FurtherCandidate, ...], cause: str) -> tuple[FurtherCandidate, ...]:
    """``judged`` with ``cause`` marked as not named (refused by a later rule)."""
    return tuple(dataclasses.replace(item, admitted=False) if item.cause == cause else item for item in judged)


def _stopped_before(path: CausePath, refused: FurtherCandidate | None, judged: tuple[FurtherCandidate, ...]
                    ) -> CausePath:
    """``path`` with the candidates judged on top of it, and the reason it stops before the best one refused:
    too little of what is left, everywhere and at its own signature."""
    if refused is None:
        return dataclasses.replace(path, further=judged)
    if refused.reshapes:
        return dataclasses.replace(path, further=judged, reasons=path.reasons + (
            f"{refused.cause} would remove {100.0 * refused.explained_fraction:.1f} % of what is left, beside a cause "
            "named on the line's path to T2 whose form it reshapes: not a further cause",))
    where = (f"{100.0 * refused.share:.1f} % of what is left at its signature ({refused.band} band, "
             f"{refused.before.significance:.1f} sigma there)")
    return dataclasses.replace(path, further=judged, reasons=path.reasons + (
        f"{refused.cause} would remove {100.0 * refused.explained_fraction:.1f} % of what is left and {where}, "
        "too little for a further cause",))


def cause_named(first: FirstRound, path: CausePath, best: CandidateScore, joint: JointFit) -> CausePath:
    """``path`` with ``best`` (whose joint fit is ``joint``) named on top of its causes: the causes named before
    it with the numbers the joint fit gave them back, the path on the model the joint fit extends, and an earlier
    cause the new one made unnecessary left out."""
    fit, before = joint.fit, path.remaining
    recalibrated_excess = first.recalibrated.excess
    named = NamedCause(cause=best.cause, fit=fit, score=best, explained_fraction=best.improvement / recalibrated_excess,
                       gain=gain_between(before.sum_of_squares, before.sum_of_squares - best.improvement, before.terms))
    causes = refitted_causes(path.causes, joint.named_effects, fit.extended_model) + (named,)
    reason = (f"{best.cause} removes {100.0 * best.improvement / recalibrated_excess:.1f} % "
              f"({best.significance:.1f} sigma)")
    extended = settled(first.search, dataclasses.replace(path, causes=causes, reasons=path.reasons + (reason,),
                                                         further=()), best.cause, joint)
    return without_unneeded(first.search, extended, first.bands) if len(extended.causes) > 1 else extended


__all__ = ["cause_named", "follow_path", "refitted_causes"]
