"""Judge: what the search concludes, one verdict per way it can end.

* :func:`kept_as_given`: the base model as given shows no discrepancy; nothing changes.
* :func:`recalibration_suffices`: the recalibrated model shows none; the cause is ``none``, recalibrated.
* :func:`no_cause_counts`: no candidate counts once refitted; ``unexplained``.
* :func:`judge`: a path of causes: named when they explain enough
  (:func:`cryod.analysis.cause_search.rules.names_the_causes`) and, leaving a discrepancy, add to the generic
  extension (:func:`cryod.analysis.cause_search.generic_judgement.against_generic`); ``unexplained`` otherwise.
"""

from __future__ import annotations

import dataclasses

from cryod.analysis.cause_search.first_round import FirstRound
from cryod.analysis.cause_search.generic_judgement import against_generic
from cryod.analysis.cause_search.joint_judgement import judge_on_path
from cryod.analysis.cause_search.joint_refit import starting_path
from cryod.analysis.cause_search.results import BoundEvidence, CausePath, FurtherCandidate, Verdict
from cryod.analysis.cause_search.rules import names_the_causes, weighed_against_generic
from cryod.analysis.decision import BaseDiscrepancy, Decision, decide, gain_between
from cryod.analysis.recalibration import Recalibration

#: Where the reason says the record cannot tell the cause named from others (rule 4 of :mod:`cryod.analysis.decision`).
TIE_MARK = "this record cannot tell"


def excess_text(recalibrated: BaseDiscrepancy) -> str:
    """The recalibrated model's held-out excess, as every reason of a recalibrated verdict starts."""
    return (f"the recalibrated base model's held-out excess is {recalibrated.excess:.4g} "
            f"({recalibrated.significance:.1f} sigma, "
            f"{100.0 * recalibrated.excess / recalibrated.terms:.2f} % of the noise power)")


def kept_as_given(first: FirstRound) -> Verdict:
    """The base model as given shows no discrepancy: the cause is ``none`` and the model is not changed, not even
    recalibrated (whatever a candidate does)."""
    decision = decide(first.as_given, [], None, None)
    return Verdict(decision=dataclasses.replace(decision, reason=decision.reason + "; the base model is kept as given"),
                   recalibrated=False, final_model=first.search.base_model, final_replay=first.base_replay,
                   remaining=first.as_given)


def recalibration_suffices(first: FirstRound) -> Verdict:
    """The recalibrated model shows no discrepancy: its parameters differed, no effect is needed; the cause is
    ``none`` and the extended model is the recalibrated one."""
    recalibrated, as_given = first.recalibrated, first.as_given
    return Verdict(
        decision=dataclasses.replace(
            first.decision, cause="none", best=None, gain=first.recalibration_gain,
            reason=(f"the recalibrated base model leaves no discrepancy beyond the noise (held-out excess "
                    f"{recalibrated.excess:.4g}, {recalibrated.significance:.1f} sigma, "
                    f"{100.0 * recalibrated.excess / recalibrated.terms:.2f} % of the noise power); the base model as "
                    f"given left {as_given.excess:.4g} ({as_given.significance:.1f} sigma): its parameters differ, "
                    "no effect is needed")),
        recalibrated=True, final_model=first.recalibration.model, final_replay=first.recalibrated_replay,
        remaining=recalibrated)


def first_round_candidates(first: FirstRound) -> tuple[FurtherCandidate, ...]:
    """The first round's candidates judged on the recalibrated model as a further cause would be: what would
    explain what an ``unexplained`` verdict leaves (none is admitted: they are first fits, not joint ones)."""
    return judge_on_path(first, starting_path(first), first.fits, {})[1]


def _unexplained(first: FirstRound, reason: str, generic: object = None, other_paths: tuple = ()) -> Verdict:
    """``unexplained`` with ``reason``: no cause named, the extended model the recalibrated one."""
    as_given, recalibrated = first.as_given, first.recalibrated
    return Verdict(
        decision=Decision(cause="unexplained", reason=reason, best=first.decision.best, base=recalibrated,
                          gain=gain_between(as_given.sum_of_squares, recalibrated.sum_of_squares, as_given.terms)),
        recalibrated=True, final_model=first.recalibration.model, final_replay=first.recalibrated_replay,
        remaining=recalibrated, generic=generic, other_paths=other_paths, further=first_round_candidates(first))


def no_cause_counts(first: FirstRound) -> Verdict:
    """No candidate counts (once refitted with the recalibration): ``unexplained``."""
    return _unexplained(first, f"{excess_text(first.recalibrated)}, and no candidate improves it significantly")


def judge(first: FirstRound, path: CausePath, other_paths: tuple[dict, ...],
          at_bound: tuple[BoundEvidence, ...] = ()) -> Verdict:
    """Step 6: the causes on ``path`` named when they remove 70 % of the recalibrated model's excess or leave no
    discrepancy; when they would be named but leave a discrepancy, only if they add to the generic extension.
    Otherwise ``unexplained``. ``other_paths``: the causes' equivalent readings; ``at_bound``: their numbers
    found at an edge of their range (:mod:`cryod.analysis.cause_search.bounds`), said in the reason when they
    stay there."""
    recalibrated, left = first.recalibrated, path.remaining
    explained = (recalibrated.excess - left.excess) / recalibrated.excess
    together = (f"{excess_text(recalibrated)}; {'; '.join(path.reasons)}: together {100.0 * explained:.1f} % of it, "
                f"and a discrepancy of {left.significance:.1f} sigma is left")
    generic = None
    if weighed_against_generic(explained, left):
        judgement = against_generic(first, path)
        if judgement.beaten_by:
            return _unexplained(first, f"{together}; {judgement.beaten_by}", judgement.generic, other_paths)
        generic = judgement.generic
    if not names_the_causes(explained, left):
        return _unexplained(first, together, other_paths=other_paths)
    return dataclasses.replace(_named(first, path, generic, other_paths), at_bound=at_bound)


def _named(first: FirstRound, path: CausePath, generic: object, other_paths: tuple[dict, ...]) -> Verdict:
    """The causes on ``path`` named; the first one is the verdict's cause. When it alone was the first round's
    choice in a tie, the reason and the tied causes are the first round's."""
    named, first_choice = path.causes[0], first.decision
    reason = f"{excess_text(first.recalibrated)}; " + ", then ".join(path.reasons)
    tie = first_choice.reason.find(TIE_MARK)
    alone_as_chosen = (len(path.causes) == 1 and first_choice.best is not None
                       and first_choice.best.cause == named.cause)
    if alone_as_chosen and tie >= 0:
        reason += "; " + first_choice.reason[tie:]
    as_given = first.as_given
    return Verdict(
        decision=Decision(cause=named.cause, reason=reason, best=named.score, base=first.recalibrated,
                          gain=gain_between(as_given.sum_of_squares,
                                            as_given.sum_of_squares - as_given.excess + path.remaining.excess,
                                            as_given.terms),
                          tied=first_choice.tied if alone_as_chosen and tie >= 0 else ()),
        recalibrated=True, causes=path.causes, final_model=path.context.base_model,
        final_replay=path.context.base_replay, remaining=path.remaining,
        final_recalibration=Recalibration.refitted(path.recalibration, path.context.base_replay),
        generic=generic, other_paths=other_paths, further=path.further)


__all__ = ["excess_text", "judge", "kept_as_given", "no_cause_counts", "recalibration_suffices"]
