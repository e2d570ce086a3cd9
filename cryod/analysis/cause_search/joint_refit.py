"""Refit jointly: the leading candidates refitted with the recalibration, and the path on the model one extends.

A candidate is fitted with the recalibration linearised (good enough to rank
the causes); before one is chosen, each leading candidate is refitted
nonlinearly together with the recalibration and the causes named so far
(:func:`cryod.analysis.refinement.refine`: a cause named before that took part
of what this one explains gives it back), scored again and judged
(:func:`refit_jointly`). The path then continues on the model the chosen
joint fit extends (:func:`settled`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from cryod.analysis.candidates import CandidateFit
from cryod.analysis.cause_search.at_signature import scores_at_signature
from cryod.analysis.cause_search.first_round import FirstRound
from cryod.analysis.cause_search.record_search import ModelPoint, RecordSearch
from cryod.analysis.cause_search.results import CausePath, JointFit, NamedCause
from cryod.analysis.cause_search.rules import leading_candidates, strained
from cryod.analysis.cause_signature import BandLayout
from cryod.analysis.decision import CandidateScore, Decision, base_discrepancy, decide, score_candidate
from cryod.analysis.recalibration import RecalibratedBase
from cryod.analysis.refinement import NamedEffect, refine
from cryod.model import CryostatModel


@dataclass(frozen=True, kw_only=True)
class JointChoice:
    """The leading candidates refitted jointly, and the choice among them.

    Attributes
    ----------
    decision : Decision
        The rules of :mod:`cryod.analysis.decision` on the refitted candidates (a tie counts a fit that needed
        the recalibration beyond a base model's spread last).
    refined : dict of str to JointFit
        Each leading candidate's joint fit.
    """

    decision: Decision
    refined: dict[str, JointFit]


def starting_path(first: FirstRound) -> CausePath:
    """The path before any cause is named: the first round's context on the recalibrated model's discrepancy."""
    context = first.context
    return CausePath(causes=(), context=context, remaining=first.recalibrated, named_effects=(),
                     recalibration=context.recalibration, reasons=())


def joint_fit(search: RecordSearch, recalibration: RecalibratedBase, fit: CandidateFit,
              named_effects: tuple[NamedEffect, ...]) -> JointFit:
    """``fit``'s effect refitted together with ``recalibration`` and the causes named before it."""
    refitted, refined_base, others = refine(search.replayer, recalibration, fit, named_effects)
    return JointFit(fit=refitted, recalibration=refined_base, named_effects=tuple(others))


def refit_jointly(search: RecordSearch, path: CausePath, fits: dict[str, CandidateFit],
                  scores: dict[str, CandidateScore], bands: BandLayout, causes: list[str] | None = None
                  ) -> JointChoice:
    """Refit the leading candidates (:func:`~cryod.analysis.cause_search.rules.leading_candidates`; ``causes``:
    these instead) jointly with the recalibration and the causes named so far on ``path``, score them against the
    path's model, hold each to its own signature in ``bands`` (:mod:`cryod.analysis.cause_search.at_signature`:
    a joint fit may move a cause where it cannot be) and apply the rules to them."""
    refined = {cause: joint_fit(search, path.recalibration, fits[cause], path.named_effects)
               for cause in (leading_candidates(scores) if causes is None else causes)}
    refitted = {cause: joint.fit for cause, joint in refined.items()}
    context = path.context
    joint_scores = scores_at_signature(bands, context.base_replay,
                                       {cause: score_candidate(context, fit, path.remaining)
                                        for cause, fit in refitted.items()},
                                       {cause: fit.replay for cause, fit in refitted.items()})
    decision = decide(path.remaining, list(joint_scores.values()),
                      lambda first, second: context.distinctness(refitted[first].replay, refitted[second].replay),
                      {cause: fit.parameter_count for cause, fit in refitted.items()},
                      {cause: strained(fit.replay) for cause, fit in refitted.items()})
    return JointChoice(decision=decision, refined=refined)


def settled(search: RecordSearch, path: CausePath, cause: str, joint: JointFit) -> CausePath:
    """``path`` on the model ``joint`` (``cause``'s joint fit) extends: its named effects, recalibration, fit
    context and what it leaves on the held-out blocks."""
    fit = joint.fit
    named_effects = joint.named_effects + (
        (NamedEffect(cause, fit.effect, tuple(fit.excluded)),) if fit.effect is not None else ())
    point = ModelPoint(recalibration=joint.recalibration, model=fit.extended_model, line=fit.line, state=fit.replay,
                       named=named_effects, carries_effects=True)
    context = search.context_on(point)
    return dataclasses.replace(path, named_effects=named_effects, recalibration=joint.recalibration, context=context,
                               remaining=base_discrepancy(context))


def refitted_causes(causes: tuple[NamedCause, ...], refitted: tuple[NamedEffect, ...], model: CryostatModel
                    ) -> tuple[NamedCause, ...]:
    """``causes`` with the numbers a joint fit gave back to those with an effect form (``refitted``, in their
    order), their parameters read from ``model``, the joint fit's extended model."""
    with_form = [named for named in causes if named.fit.effect is not None]
    effects = dict(zip([id(named) for named in with_form], refitted))
    return tuple(
        dataclasses.replace(named, fit=dataclasses.replace(named.fit, effect=effects[id(named)].effect,
                                                           parameters=effects[id(named)].effect.describe(model)))
        if id(named) in effects else named for named in causes)


__all__ = ["JointChoice", "joint_fit", "refit_jointly", "refitted_causes", "settled", "starting_path"]
