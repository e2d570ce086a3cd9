"""Causes weighed against the generic extension: whether they add to what a data-driven model already does.

Where causes leave a discrepancy, they may stand in for something outside the
catalogue. The generic extension (:mod:`cryod.analysis.generic_extension`) is
fitted on the model without them and on the model with them; the causes are
what the record shows only if the second does significantly better on the
held-out blocks (:func:`cryod.analysis.cause_search.rules.adds_what_a_cause_must`).
"""

from __future__ import annotations

from dataclasses import dataclass

from cryod.analysis.cause_search.first_round import FirstRound
from cryod.analysis.cause_search.results import CausePath, ReplayedModel
from cryod.analysis.cause_search.rules import adds_what_a_cause_must
from cryod.analysis.decision import significance
from cryod.analysis.generic_extension import GenericExtension, containing_families, fit_generic_extension


@dataclass(frozen=True, kw_only=True)
class GenericComparison:
    """The generic extension fitted on two models, and what the second's causes add on the held-out blocks.

    Attributes
    ----------
    added : float
        Held-out sum of squares of the extension on the first model less that on the second (noise units).
    significance : float
        ``added`` in standard deviations of the difference between the two predictions.
    without_causes, with_causes : GenericExtension
        The extension on each model.
    """

    added: float
    significance: float
    without_causes: GenericExtension
    with_causes: GenericExtension

    @property
    def causes_add(self) -> bool:
        """Whether the causes add what a cause must (25 and 5 sigma)."""
        return adds_what_a_cause_must(self.added, self.significance)


@dataclass(frozen=True, kw_only=True)
class GenericJudgement:
    """Causes weighed against the generic extension (:func:`against_generic`).

    Attributes
    ----------
    beaten_by : str
        Why the causes are not named ('' when they add what a cause must).
    generic : GenericExtension or None
        The extension that goes with the verdict (None when a family was left out of the comparison: it is
        fitted again with every family).
    """

    beaten_by: str
    generic: GenericExtension | None


def added_to_generic(first: FirstRound, without: ReplayedModel, with_causes: ReplayedModel,
                     left_out: tuple = ()) -> GenericComparison:
    """What the causes of ``with_causes`` add to the generic extension over ``without``'s; ``left_out``: families
    of the extension not fitted. Each extension is fitted on its model's replay, without a linearised
    recalibration, and both are judged on the first round's held-out blocks."""
    search, line = first.search, first.context.base_line
    alone = fit_generic_extension(search.context(without.model, line, without.replay), without.remaining, left_out)
    on_causes = fit_generic_extension(search.context(with_causes.model, line, with_causes.replay),
                                      with_causes.remaining, left_out)
    context = first.context
    a, b = alone.fit.replay, on_causes.fit.replay
    added = sum(context.chi_square(a, context.held_out_mask)) - sum(context.chi_square(b, context.held_out_mask))
    return GenericComparison(added=added, significance=significance(added, context.distinctness(a, b)),
                             without_causes=alone, with_causes=on_causes)


def further_cause_comparison(first: FirstRound, before: CausePath, after: CausePath, cause: str
                             ) -> GenericComparison:
    """A further cause ``cause`` that leaves a discrepancy, weighed against the generic extension on the model
    without it (``before``): a leftover of the causes named (a drift's spline that is a little too stiff) is not
    taken for another cause. The family that contains ``cause`` is left out
    (:func:`cryod.analysis.generic_extension.containing_families`)."""
    return added_to_generic(first, before.replayed(), after.replayed(), containing_families([cause]))


def against_generic(first: FirstRound, path: CausePath) -> GenericJudgement:
    """Whether the causes on ``path``, which leave a discrepancy, add anything significant to the generic
    extension.

    The extension fitted on the recalibrated model alone is compared, on the held-out blocks, with the extension
    fitted on top of the causes; if the causes add less than a candidate must (5 sigma and 25), they stand in for
    something the catalogue does not have. A family that can itself represent a cause named
    (:data:`~cryod.analysis.generic_extension.CONTAINING_FAMILIES`: the reading offsets, a free slow series on T2
    and on T5, contain the cold end's drift) is left out of this comparison: against it a cause cannot add, whether
    it is right or not, and the cause says with two numbers (its coupling) what the family says with a free series.
    """
    left_out = containing_families(named.cause for named in path.causes)
    recalibrated = ReplayedModel(model=first.recalibration.model, replay=first.recalibrated_replay,
                                 remaining=first.recalibrated)
    comparison = added_to_generic(first, recalibrated, path.replayed(), left_out)
    if comparison.causes_add:
        return GenericJudgement(beaten_by="", generic=None if left_out else comparison.with_causes)
    alone = comparison.without_causes
    return GenericJudgement(
        beaten_by=(f"with the generic extension ({' + '.join(alone.used)}) the causes add only "
                   f"{comparison.added:.4g} ({comparison.significance:.1f} sigma) on the held-out blocks: they stand "
                   "in for something outside the catalogue, and no physical cause is named"),
        generic=None if left_out else alone)


__all__ = ["GenericComparison", "GenericJudgement", "added_to_generic", "against_generic",
           "further_cause_comparison"]
