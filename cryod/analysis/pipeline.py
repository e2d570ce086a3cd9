"""One analysis of one record: the cause search's steps, in order.

:func:`analyze` is what ``cryod analyze`` runs; the figures, the report and the
JSON are made from the :class:`~cryod.analysis.cause_search.results.Analysis`
it returns. The steps live in :mod:`cryod.analysis.cause_search`, the rules
they apply in :mod:`cryod.analysis.cause_search.rules`:

1. Replay the record with the base model as given and measure the noise
   (:func:`~cryod.analysis.cause_search.first_round.replay_record`).
2. Recalibrate the base model's own parameters within their tolerances
   (:func:`~cryod.analysis.cause_search.first_round.recalibrate_base`).
3. Rank the candidates: fit every cause, judge each on the held-out blocks
   (:func:`~cryod.analysis.cause_search.first_round.rank_candidates`). A base
   model as given that shows no discrepancy is kept; a recalibrated one that
   shows none is the verdict ``none``.
4. Follow paths: refit the leading candidates jointly with the recalibration
   (:mod:`~cryod.analysis.cause_search.joint_refit`) and name causes one
   after another from the best, and from the others when a discrepancy is
   left (:func:`~cryod.analysis.cause_search.path_choice.follow_paths`).
5. Read the causes named the other way round
   (:func:`~cryod.analysis.cause_search.path_choice.read_the_other_way_round`),
   and re-examine a cause's number at an edge of its range
   (:func:`~cryod.analysis.cause_search.bounds.examine_bounds`).
6. Judge: the causes named, or ``unexplained``
   (:func:`~cryod.analysis.cause_search.verdict.judge`).
7. Ask whether the base model is further off than the recalibration allows
   (:func:`~cryod.analysis.cause_search.base_model_off.judged_beyond_recalibration`:
   the steps above again on the widened model).
8. Describe what is left, and extend the model generically where a
   discrepancy remains
   (:func:`~cryod.analysis.cause_search.what_is_left.describe_what_is_left`).
"""

from __future__ import annotations

from cryod.analysis.candidates import CANDIDATE_CAUSES
from cryod.analysis.cause_search.bounds import examine_bounds, merged_evidence
from cryod.analysis.cause_search.base_model_off import (
    WIDER_RECALIBRATION, explained_by_widening, judged_beyond_recalibration, widened_recalibration,
)
from cryod.analysis.cause_search.first_round import FirstRound, rank_candidates, recalibrate_base, replay_record
from cryod.analysis.cause_search.path_choice import ReadPath, follow_paths, read_the_other_way_round
from cryod.analysis.cause_search.record_search import RecordSearch, SearchScope, timed
from cryod.analysis.cause_search.results import Analysis, Verdict
from cryod.analysis.cause_search.rules import improving_causes
from cryod.analysis.cause_search.verdict import (
    judge, kept_as_given, no_cause_counts, recalibration_suffices,
)
from cryod.analysis.cause_search.what_is_left import describe_what_is_left
from cryod.analysis.record_data import RecordData
from cryod.analysis.recalibration import Recalibration
from cryod.model import CryostatModel


def analyze(data: RecordData, base_model: CryostatModel, causes=CANDIDATE_CAUSES) -> Analysis:
    """Analyse one record against a model.

    Parameters
    ----------
    data : RecordData
    base_model : CryostatModel
    causes : sequence of str
        Candidate causes to try (default: all).

    Returns
    -------
    Analysis

    Raises
    ------
    cryod.analysis.usability.UnusableRecordError
        When the record cannot be analysed, saying what it is missing.
    """
    within = search_causes(RecordSearch.on(data, base_model, SearchScope(causes=tuple(causes))))

    def search_on_widened(model: CryostatModel) -> Analysis:
        scope = SearchScope(causes=tuple(improving_causes(within.scores) or causes), screen_when_fitting=False,
                            widen=False, most_causes=1)
        return search_causes(RecordSearch.on(data, model, scope, cycle_from=within.context.replayer))

    judged = judged_beyond_recalibration(within, search_on_widened)
    with timed(judged.timings_s, "residual and generic extension"):
        analysis = describe_what_is_left(judged)
    return analysis


def search_causes(search: RecordSearch) -> Analysis:
    """Steps 1 to 6 on one base model (see the module doc)."""
    first = rank_candidates(recalibrate_base(replay_record(search)))
    if not first.as_given.present:
        return _analysis(first, kept_as_given(first))
    widened = None
    if search.scope.widen and any(row.at_tolerance for row in first.recalibration.table()):
        with first.search.timed(WIDER_RECALIBRATION):
            widened = widened_recalibration(first.search.replayer, search.base_model, first.base_line)
    # When the widened recalibration alone explains the record, only the first cause is looked for within the
    # tolerance: what a catalogue cause alone would say (cryod.analysis.cause_search.base_model_off).
    first_only = widened is not None and explained_by_widening(widened, search.base_model, first.context)
    with first.search.timed("naming the causes"):
        verdict = name_causes(first, 1 if first_only else search.scope.most_causes)
    return _analysis(first, verdict, widened)


def name_causes(first: FirstRound, most: int) -> Verdict:
    """Steps 4 to 6: the verdict on the recalibrated model, naming ``most`` causes at most (with 1, one path and
    no other reading)."""
    if not first.recalibrated.present:
        return recalibration_suffices(first)
    followed = follow_paths(first, most)
    if followed is None:
        return no_cause_counts(first)
    read = read_the_other_way_round(first, followed) if most > 1 else ReadPath(path=followed.path)
    path, at_bound = examine_bounds(first, read.path)
    return judge(first, path, read.other_paths, merged_evidence(read.path.at_bound, at_bound))


def _analysis(first: FirstRound, verdict: Verdict, widened: Recalibration | None = None) -> Analysis:
    """The search's analysis: what the first round found and the verdict."""
    search = first.search
    return Analysis(
        data=search.data, base_model=search.base_model, base_line=first.base_line, base_replay=first.base_replay,
        noise_rms_K=search.noise_rms_K, fits=first.fits, scores=first.scores, decision=verdict.decision,
        context=first.context, timings_s=search.timings_s, recalibration=first.recalibration,
        recalibrated=verdict.recalibrated, recalibration_gain=first.recalibration_gain, causes=verdict.causes,
        final_model=verdict.final_model, final_replay=verdict.final_replay, base_discrepancy=first.as_given,
        final_recalibration=verdict.final_recalibration, remaining=verdict.remaining, generic=verdict.generic,
        widened=widened, other_paths=verdict.other_paths, further=verdict.further, at_bound=verdict.at_bound)


__all__ = ["Analysis", "analyze", "name_causes", "search_causes"]
